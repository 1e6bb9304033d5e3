"""PointGoal navigation with an odometer standing in for GPS+Compass: the metrics
(:mod:`.metrics`, habitat-lab's definitions), the map-and-plan agent that knows only its odometry
(:mod:`.agent`) and the closed loop of one episode (:mod:`.episode`)."""

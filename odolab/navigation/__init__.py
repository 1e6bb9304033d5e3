"""PointGoal navigation with an odometer standing in for GPS+Compass: the metrics
(:mod:`.metrics`, habitat-lab's definitions)."""

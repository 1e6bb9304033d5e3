"""The simulator and what is rendered from it: floor plans and textures (``scenes``, ``textures``), ray
casting (``camera``), sensor and actuation noise (``noise``, ``redwood``), motion and planning
(``agent``, ``planner``), the step-wise environment, PointNav episodes and their cache, touring routes,
episode splits and pair data sets, and training shards."""

"""The simulator: floor plans, textures, ray casting, sensor and actuation noise, motion, planning."""

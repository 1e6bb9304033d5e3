"""Readers and writers of files: trajectories (KITTI, TUM) and real RGB-D recordings."""

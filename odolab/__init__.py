"""odolab: classical and learned visual odometry, compared side by side on noisy RGB-D episodes.

Import :mod:`odolab.api` for the public interface. Importing ``odolab`` itself is cheap: no torch,
no Open3D.
"""

__version__ = "0.1.0"

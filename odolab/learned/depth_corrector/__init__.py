"""A learned depth corrector under any odometer: a small U-Net trained against the simulator's
noiseless depth (dense, per-pixel supervision), and the composites ``denoised(X)`` (odometer X on
the corrected depth) and ``noiseless-depth(X)`` (X on the simulator's noiseless depth: the
ceiling, an oracle).

| file | its one job |
|---|---|
| ``config.py`` | the network shape and the training recipe (TOML) |
| ``model.py`` | the U-Net: RGB-D in, corrected depth and its error's spread out |
| ``checkpoint.py`` | the model file (``weights_only=True``) |
| ``train.py`` | ``python -m odolab.learned.depth_corrector.train``: resumable training, validation by distance |
| ``odometer.py`` | ``denoised(X)`` and ``noiseless-depth(X)`` |
"""

"""The learned wing: every learned odometer and what they share (torch lives here and nowhere below).

| package | what it holds |
|---|---|
| ``training/`` | what every learned odometer shares: device and precision, safe model files, TOML recipes, the resumable epoch loop, curves, data-parallel training |
| ``robust_vo/`` | the paper's robust VO (``robust-vo``) |
| ``deepvo/`` | DeepVO (``deepvo``), written against ``odolab.api`` and ``training`` only, as a plug-in would be |
| ``depth_corrector/`` | the learned depth corrector (``denoised(X)``, and the oracle ``noiseless-depth(X)``) |
| ``pose_corrector/`` | the learned correction of a classical estimate (``corrected(X)``) |

Their shipped model files live in ``odolab/data/``. Importing this package imports none of them.
"""

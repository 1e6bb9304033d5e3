"""The paper's robust learned visual odometry (Zhao et al. ICCV 2021; docs/reference-facts.md section 3).

| file | its one job |
|---|---|
| ``config.py`` | every switch (model, inputs, stages, data) as frozen dataclasses read from TOML |
| ``inputs.py`` | psi(I): RGB, depth, discretised depth, soft top-down projection, on torch batches |
| ``model.py`` | ResNet-18 + GroupNorm, compression conv, FC head; SepAct / Unified / ActEmbed |
| ``motion.py`` | planar SE(2) on batches, the frame-swap and mirror maps, the GeoInv loss |
| ``batches.py`` | training samples (which pair, swapped, mirrored) to tensors |
| ``train.py`` | ``python -m odolab.learned.robust_vo.train``: resumable stages, validation curves, export |
| ``checkpoint.py`` | the model file (``weights_only=True``) |
| ``odometer.py`` | ``robust-vo``, the registered :class:`~odolab.api.Odometer` |
"""

"""DeepVO (Wang et al., ICRA 2017; docs/reference-facts.md section 4) as a baseline odometer, written
against ``odolab.api`` and ``odolab.learned.training`` only.

| file | its one job |
|---|---|
| ``config.py`` | network widths and the training recipe (frozen dataclasses from TOML) |
| ``model.py`` | FlowNetSimple-like encoder of two stacked frames, 2-layer LSTM, linear to (dx, dz, dyaw) |
| ``train.py`` | ``python -m odolab.learned.deepvo.train``: short windows of episodes, resumable, validation curves |
| ``odometer.py`` | ``deepvo``: the LSTM state carries across ``step`` calls, ``reset`` clears it |
"""

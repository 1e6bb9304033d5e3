"""A learned correction of a classical estimate (after DPC-Net, Peretroukhin and Kelly, RA-L 2018):
``corrected(X)`` resamples the current frame into the previous view by X's estimate and a small CNN
reads what is left and answers a planar correction of X's motion and its variance.

| file | its one job |
|---|---|
| ``config.py`` | the network shape and the training recipe (TOML) |
| ``model.py`` | the CNN, its inputs (the warped pair, the action) and how a correction is applied |
| ``checkpoint.py`` | the model file (``weights_only=True``) and where the shipped ones lie |
| ``estimates.py`` | X's estimates on the training pairs, computed once and stored beside the data (Ray tasks) |
| ``train.py`` | ``python -m odolab.learned.pose_corrector.train``: resumable training, validation against X alone |
| ``odometer.py`` | ``corrected(X)`` |
"""

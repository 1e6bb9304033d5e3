"""The `Odometer` interface and its registry, per-odometer options, what composite odometers share, and the reference rows (`ground-truth`, `action-prior`)."""

"""What ``python -m odolab.bench`` times: the simulator, episodes, odometers, navigation and training
(``speed.py``), and the evaluator against evo (``evaluate_speed.py``)."""

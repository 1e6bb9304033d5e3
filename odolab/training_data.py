"""``python -m odolab.training_data``: the command line lives in :mod:`odolab.cli.training_data`, the library in
:mod:`odolab.sim.training_data`."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("odolab.cli.training_data", run_name="__main__", alter_sys=True)

"""``python -m odolab.action_prior``: the command line lives in :mod:`odolab.cli.action_prior`, the library in
:mod:`odolab.odometry.action_prior`."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("odolab.cli.action_prior", run_name="__main__", alter_sys=True)

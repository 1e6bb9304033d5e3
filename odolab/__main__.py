"""``python -m odolab``: the ``odolab`` command (:mod:`odolab.cli.commands`)."""

from odolab.commands import console

if __name__ == "__main__":
    console()

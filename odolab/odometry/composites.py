"""What odometers built on others share (``fused(a,b)``, ``manhattan(a)``): loading their inputs,
each with its own options from a TOML file (``options_file``, as ``compare --config``)."""

from __future__ import annotations

from odolab.odometry.odometer import REGISTRY, Odometer, split_odometer_names
from odolab.odometry.options import check_options, read_options_file

__all__ = ["load_inputs", "one_input"]


def one_input(owner: str, inputs: object) -> str:
    """The one inner odometer name of ``owner(inputs)`` (``denoised(icp)``: ``icp``); ``ValueError``
    for none or several."""
    names = split_odometer_names(inputs) if isinstance(inputs, str) else []
    if len(names) != 1:
        raise ValueError(
            f"{owner} takes one inner odometer, e.g. {owner}(open3d-rgbd), got {len(names)}"
            + (f" ({', '.join(names)})" if names else "")
        )
    return names[0]


def load_inputs(owner: str, names: list[str], options_file: str = "") -> dict[str, Odometer]:
    """The odometers ``names`` (inputs of the composite ``owner``), each built with its table of
    ``options_file`` (``[odometers."icp"] key = value``). ``ValueError`` naming the file: a table for
    a name that is not an input, an option the input does not take, a value it refuses."""
    if not isinstance(options_file, str):
        raise ValueError(f"{owner}: options_file must be a path (a string), got {options_file!r:.80}")
    tables = read_options_file(options_file) if options_file else {}
    stray = [n for n in tables if n not in names]
    if stray:
        raise ValueError(
            f"{options_file}: options for {stray[0]!r}, which is not an input of {owner} ({', '.join(names)})"
        )
    inputs: dict[str, Odometer] = {}
    for n in names:
        opts = tables.get(n, {})
        try:
            check_options(n, REGISTRY.resolve(n), opts)
        except ValueError as exc:
            raise ValueError(f"{options_file}: {exc}") from None
        try:
            inputs[n] = REGISTRY.load(n, **opts)
        except ValueError as exc:  # a value its own checks refuse (a range, NaN): say where it came from
            if not opts:
                raise
            raise ValueError(f'{options_file}: [odometers."{n}"] {exc}') from None
    return inputs

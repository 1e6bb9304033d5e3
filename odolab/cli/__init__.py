"""The command lines: each module here parses one command's arguments, calls the library and prints
(``compare``, ``evaluate``, ``navigate``, ``navigation_diff``, ``simcard``, ``bench``,
``training_data``, ``action_prior``, ``calibrate_fusion``; ``commands`` is the ``odolab`` console
script). :mod:`odolab.cli.args` is their shared plumbing (argument types, output checks, one-line
errors and exit code 2); its names are importable from here too. The library below never imports
this package: it raises typed errors (:mod:`odolab.core.errors`) that the commands word with their options.
"""

from odolab.cli.args import (
    MAX_ERROR_CHARS,
    ArgumentParser,
    UsageError,
    check_not_nested,
    check_output_dir,
    check_output_file,
    check_ray_option,
    check_replaceable,
    check_report_dir,
    execution_of,
    file_arg,
    folder_owner,
    given_options,
    number,
    path_arg,
    pinhole,
    run_cli,
)

__all__ = [
    "MAX_ERROR_CHARS",
    "ArgumentParser",
    "UsageError",
    "check_not_nested",
    "check_output_dir",
    "check_output_file",
    "check_ray_option",
    "check_replaceable",
    "check_report_dir",
    "execution_of",
    "file_arg",
    "folder_owner",
    "given_options",
    "number",
    "path_arg",
    "pinhole",
    "run_cli",
]

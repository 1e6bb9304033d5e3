"""The studies' command lines, one for each study of ``studies/`` (:data:`STUDIES`):

    odolab study NAME [options]   = python -m studies.<module> [options]
    odolab study --help           lists them

Every study that computes units (``e-table``, ``ablations``, ``kitti-style``, ``noise-robustness``,
``turns-by-depth``) takes the same options (:func:`add_study_options`: ``--scale``, ``--out``,
``--ray-address``, ``--serial``, ``--redraw``, ``--quiet``), the ablations also ``--rows``, the
e-table and noise-robustness also ``--scenes`` (mesh files: their test split); the
probes and the index take their own. Each study module holds a ``run(args)`` that does the work;
``args.command`` is the command as typed, for its report. Mistakes are one line and exit code 2.
"""

from __future__ import annotations

import importlib
import shlex
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from odolab.cli.args import (
    ArgumentParser,
    UsageError,
    add_setting,
    exit_process,
    file_arg,
    path_arg,
    quiet_broken_pipe,
    run_cli,
    setting_type,
)
from odolab.config import range_text

__all__ = ["STUDIES", "command", "exit_process", "main", "study", "study_parser"]

#: study name -> (its module, one line of help)
STUDIES: dict[str, tuple[str, str]] = {
    "e-table": ("studies.e_table", "every odometer's per-step error over seeds, beside the paper's Table S4"),
    "ablations": ("studies.ablations", "the paper's Table 2: each row trained, scored per step and navigated"),
    "kitti-style": ("studies.kitti_style", "every odometer on long routes: KITTI t_rel / r_rel, ATE, drift"),
    "noise-robustness": ("studies.noise_robustness", "every odometer's per-step error against sensor noise"),
    "turns-by-depth": ("studies.turns_by_depth", "turns binned by how far the view reaches"),
    "reports-index": ("studies.reports_index", "reports/index.html: a page linking every report"),
    "robust-vo-scaling": ("studies.robust_vo.scaling", "the robust VO's validation error against samples and hours"),
    "forward-dz-probe": ("studies.robust_vo.forward_dz_probe", "what limits the robust VO's forward dz"),
    "derotation-probe": ("studies.robust_vo.derotation_probe", "a fresh turn network with and without the warp"),
    "precision-check": ("studies.robust_vo.precision_check", "a short recipe trained in fp32 and bf16"),
    "inference-precision": ("studies.robust_vo.inference_precision", "the shipped robust VO run in fp32 and bf16"),
}

#: The scales every computing study defines (studies.framework.SCALES), with their help.
SCALE_HELP = {
    "ci": "seconds",
    "cpu": "the committed report (default)",
    "paper": "the paper's size, for a cluster",
}


def add_study_options(ap: ArgumentParser, config) -> None:
    """The options every computing study shares, given its definition ``config``
    (:class:`studies.framework.StudyConfig`: its scales and its name)."""
    ap.add_argument(
        "--scale",
        choices=list(config.scales),
        default="cpu",
        help="; ".join(f"{s}: {SCALE_HELP.get(s, 'see the study' + chr(39) + 's definition')}" for s in config.scales),
    )
    ap.add_argument(
        "--out",
        type=path_arg("--out"),
        default=None,
        help=f"report folder (default reports/{config.name.replace('_', '-')})",
    )
    ap.add_argument("--ray-address", default=None, help="Ray cluster for the units (default: a local instance)")
    ap.add_argument("--serial", action="store_true", help="run the units one after another in this process")
    ap.add_argument("--redraw", action="store_true", help="rebuild the report from saved results only")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")


def _computing(ap: ArgumentParser, module) -> None:
    """Options of a study that computes units: the shared ones, from its definition."""
    try:
        config = module.study_config()
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    ap.description = config.title
    add_study_options(ap, config)


def _cache_option(ap: ArgumentParser) -> None:
    """``--cache``: where a study's episodes are kept between its units and its runs."""
    from odolab.reporting.pipeline import DEFAULT_CACHE

    ap.add_argument(
        "--cache",
        type=path_arg("--cache"),
        default=DEFAULT_CACHE,
        help=f"episode cache the units read and add to; a study's episodes take gigabytes (default {DEFAULT_CACHE})",
    )


def _with_scenes(ap: ArgumentParser, module) -> None:
    """A computing study whose episodes may run in mesh files (``--scenes``: their test split)."""
    from odolab.cli.args import add_scene_options

    _computing(ap, module)
    add_scene_options(ap, family=False)
    _cache_option(ap)


def _ablations(ap: ArgumentParser, module) -> None:
    _computing(ap, module)
    _cache_option(ap)
    ap.add_argument(
        "--rows",
        default=None,
        metavar="N,N,...",
        help="compute only these rows' units (their models, errors and navigation; the report shows every "
        "row from the saved results): a long scale in chunks, each committed as it finishes",
    )


def _reports_index(ap: ArgumentParser, module) -> None:
    ap.add_argument(
        "--reports",
        type=path_arg("--reports"),
        default=module.DEFAULT_REPORTS,
        help=f"the reports folder (default {module.DEFAULT_REPORTS})",
    )


def _scaling(ap: ArgumentParser, module) -> None:
    ap.add_argument(
        "--runs",
        type=path_arg("--runs"),
        nargs="+",
        default=[Path("reports/robust-vo/shipped"), Path("reports/robust-vo/shipped-341")],
        help="training report folders, each with a curves.csv (default: the shipped recipes' runs)",
    )
    ap.add_argument(
        "--classical",
        type=path_arg("--classical"),
        default=Path("reports/compare-val-20x100/table_per_action.csv"),
        help="a compare run's table_per_action.csv (default reports/compare-val-20x100/...: validation "
        "episodes, as the curves)",
    )
    ap.add_argument(
        "--out",
        type=path_arg("--out"),
        default=Path("reports/robust-vo/scaling"),
        help="where scaling.png, scaling-hours.png and scaling.csv go (default reports/robust-vo/scaling)",
    )


def _forward_dz_probe(ap: ArgumentParser, module) -> None:
    ap.add_argument(
        "--config",
        type=path_arg("--config"),
        default=Path("studies/robust_vo/shipped.toml"),
        help="recipe whose val data is read (made by its training command; of the probed model's input size)",
    )
    ap.add_argument(
        "--checkpoint",
        type=path_arg("--checkpoint"),
        default=module.SHIPPED,
        help="robust-VO model file to probe (default: the shipped model)",
    )
    add_setting(ap, "--passes", module.ProbeSettings, "passes")
    ap.add_argument("--out", type=file_arg("--out"), default=None, help="also write the report to this text file")


def _derotation_probe(ap: ArgumentParser, module) -> None:
    ap.add_argument("--config", type=path_arg("--config"), default="studies/robust_vo/shipped.toml")
    add_setting(ap, "--seconds", module.ProbeSettings, "seconds")
    add_setting(ap, "--samples", module.ProbeSettings, "samples")
    ap.add_argument("--derotate", action="store_true", help="warp the current frame by the commanded turn")


def _precision_check(ap: ArgumentParser, module) -> None:
    ap.add_argument(
        "--out",
        type=path_arg("--out"),
        default=Path("reports") / "robust-vo" / "precision",
        help="where runs.csv and comparison.md go (default reports/robust-vo/precision)",
    )
    ap.add_argument(
        "--work",
        type=path_arg("--work"),
        default=Path("runs") / "robust-vo" / "precision",
        help="training states, one folder per run (default runs/robust-vo/precision)",
    )
    ap.add_argument(
        "--seeds",
        type=setting_type("--seeds", module.CheckSettings, "seeds"),
        nargs="+",
        default=list(module.CheckSettings().seeds),
        help=f"at least two different seeds, each in {range_text(module.CheckSettings, 'seeds')} (default "
        f"{' '.join(map(str, module.CheckSettings().seeds))})",
    )


def _inference_precision(ap: ArgumentParser, module) -> None:
    add_setting(ap, "--episodes", module.ProbeSettings, "episodes")
    add_setting(ap, "--max-steps", module.ProbeSettings, "max_steps")
    ap.add_argument(
        "--out",
        type=path_arg("--out"),
        default=Path("reports") / "robust-vo" / "inference-precision",
        help="where summary.json goes (default reports/robust-vo/inference-precision)",
    )


#: study name -> what adds its options to its parser, given its module
OPTIONS: dict[str, Callable[[ArgumentParser, object], None]] = {
    "e-table": _with_scenes,
    "ablations": _ablations,
    "kitti-style": _computing,
    "noise-robustness": _with_scenes,
    "turns-by-depth": _computing,
    "reports-index": _reports_index,
    "robust-vo-scaling": _scaling,
    "forward-dz-probe": _forward_dz_probe,
    "derotation-probe": _derotation_probe,
    "precision-check": _precision_check,
    "inference-precision": _inference_precision,
}


def study_parser(name: str, prog: str) -> ArgumentParser:
    """The argument parser of study ``name`` (its module imported now), its usage named ``prog``."""
    module = importlib.import_module(STUDIES[name][0])
    description = (module.__doc__ or STUDIES[name][1]).strip().split("\n")[0].replace("``", "")
    ap = ArgumentParser(prog=prog, description=description)
    OPTIONS[name](ap, module)
    return ap


def study(name: str, argv: Sequence[str] | None = None, prog: str | None = None) -> int:
    """Run study ``name`` with the command-line arguments ``argv`` (default ``sys.argv[1:]``):
    parse them, then the module's ``run(args)``, ``args.command`` being the command as typed and
    ``args.argv`` its options.
    :class:`UsageError` for a mistake (:func:`command` words it in one line)."""
    module = STUDIES[name][0]
    prog = prog or f"python -m {module}"
    argv = list(sys.argv[1:] if argv is None else argv)
    args = study_parser(name, prog).parse_args(argv)
    args.command = " ".join([prog, *map(shlex.quote, argv)])
    args.argv = argv  # the options as typed (which were given, not defaulted)
    return importlib.import_module(module).run(args)


def main(argv: Sequence[str] | None = None) -> int:
    """``odolab study NAME [options]``: ``UsageError`` for a missing or unknown name."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        width = max(map(len, STUDIES))
        listing = "\n".join(f"  {n:<{width}}  {text}  (python -m {m})" for n, (m, text) in STUDIES.items())
        text = f"usage: odolab study NAME [options]   (odolab study NAME --help for its options)\n\nstudies:\n{listing}"
        if not args:
            raise UsageError(f"expected a study name, one of {', '.join(STUDIES)}")
        try:
            print(text, flush=True)
        except BrokenPipeError:  # odolab study --help | head -1: the reader went away, no error
            quiet_broken_pipe()
        return 0
    name = args[0]
    if name.startswith("-"):
        raise UsageError(f"expected the study's name first (odolab study NAME [options]), got {name!r}")
    if name not in STUDIES:
        import difflib

        near = difflib.get_close_matches(name.lower().replace("_", "-"), STUDIES, n=1, cutoff=0.6)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        raise UsageError(f"unknown study {name!r}; expected one of {', '.join(STUDIES)}{hint}")
    return study(name, args[1:], prog=f"odolab study {name}")


def command(name: str, argv: Sequence[str] | None = None) -> int:
    """``python -m <the study's module>``: :func:`study` under :func:`~odolab.cli.args.run_cli`
    (one line and exit 2 for a user's mistake; 130 for Ctrl-C)."""
    prog = f"python -m {STUDIES[name][0]}"
    return run_cli(lambda args: study(name, args, prog), prog, argv)

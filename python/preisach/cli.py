"""The ``preisach`` command line. Usage errors: one line, exit 2. Bad data: one line,
exit 1. Never a traceback for a user's mistake. Output paths and optional dependencies
are checked before any work; a closed pipe (``| head``) ends the command quietly."""
from __future__ import annotations

import argparse
import os
import re
import sys
import warnings
from typing import Any, Callable, Optional, Sequence

import numpy as np

EXAMPLES = {
    "identify": "example: preisach identify examples/paper_ident.csv --n-h 40 -o model.json",
    "predict": "example: preisach predict model.json examples/paper_ident.csv -o predicted.csv",
    "invert": "example: preisach invert model.json reference.csv -o input.csv\n"
              "         preisach invert aug.json reference.csv -o input.csv --bandwidth 2000\n"
              "         preisach invert model.json reference.csv -o input.csv --method interpolated --lookahead 100",
    "simulate": "example: preisach simulate --preset paper input.csv -o measured.csv",
    "diagnose": "example: preisach diagnose train.csv --holdout steps.csv --holdout sine50.csv "
                "--json report.json --save-model aug.json --plots plots/",
    "demo": "example: preisach demo --out preisach-demo        (then open preisach-demo/report.md)\n"
            "         preisach demo --quick --no-plots --out /tmp/d",
    "import-mat": "example: preisach import-mat capture.mat --list\n"
                  "         preisach import-mat capture.mat --u \"u_dac\" --y \"y_sensor\" -o ident.csv\n"
                  "         preisach import-mat data.mat --t t --u 'M(:,1)' --y 2 -o ident.csv",
    "compare": "example: preisach compare model.json ident.csv steps.csv --plot compare.png\n"
               "fit [%] = 100 (1 - |y - y_model| / |y - mean(y)|), as MATLAB's compare",
    "export-mat": "example: preisach export-mat model.json -o model.mat\n"
                  "then in MATLAB: S = load('model.mat'); S.weights(i, j) is the mass of cell (beta_i, alpha_j)",
}

# Output options, checked before any work: attribute -> (flag, is a directory).
OUTPUTS = {"output_path": ("-o", False), "json": ("--json", False), "save_model": ("--save-model", False),
           "plots": ("--plots", True), "plot": ("--plot", False), "out": ("--out", True)}

# argparse takes "-1e3" for an option; a number in any float spelling is a value.
_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-inf(inity)?$", re.IGNORECASE)


class UsageError(Exception):
    """A mistake in how the command was called (exit 2)."""


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NUMBER

    def error(self, message: str) -> Any:  # one line, no usage dump
        raise UsageError(f"{self.prog}: {message} (see --help)")


class _Help(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Every option's default in --help (unless its help already says it, or there is
    none to show); the examples in the epilog kept as written."""

    def _get_help_string(self, action: argparse.Action) -> Optional[str]:
        text = action.help or ""
        if action.required or action.default is None or action.default is False or "default" in text:
            return text
        return super()._get_help_string(action)


def _cmd_identify(a: argparse.Namespace) -> int:
    from preisach._validate import as_n_h, as_range, check_range_reached
    from preisach.io import read_record
    from preisach.model import PreisachModel, PreisachWarning

    rec = read_record(a.data, ["u", "y"])
    if a.range is not None:
        check_range_reached("--range", rec["u"], as_range("--range", a.range), as_n_h(a.n_h))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PreisachWarning)
        model = PreisachModel.fit(rec["u"], rec["y"], a.n_h, u_range=a.range, reg=a.reg, solver=a.solver,
                                  output=a.output, diagonal_floor=a.diagonal_floor)
    model.save(a.output_path)
    rep = model.report
    print(f"identified n_h={model.n_h} on u_range=({model.u_range[0]:.6g}, {model.u_range[1]:.6g}) from "
          f"{rep.n_samples} samples ({rep.n_rows} distinct states, {rep.reversals} reversals) with {rep.solver}")
    print(f"training RMSE {rep.rmse:.6g}; offset {model.offset:.6g}; cells never excited {rep.cells_never_excited}")
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    print(f"wrote {a.output_path}")
    return 0


def _load_chain(path: str) -> Any:
    """A model, chain or stage file as a chain (``preisach.load``)."""
    from preisach.chain import Chain, load

    obj = load(path)
    return obj if isinstance(obj, Chain) else Chain(obj)


def _load_for_export(path: str) -> tuple[Any, Optional[dict[str, Any]]]:
    """The identified model of a model, chain or stage file, and the chain's dict
    without that model's block (None for a plain model)."""
    from preisach.chain import load
    from preisach.model import PreisachModel

    obj = load(path)
    if isinstance(obj, PreisachModel):
        return obj, None
    model = obj.model
    if model is None:
        raise ValueError(f"{path}: a chain ({' -> '.join(obj.kinds())}) with no identified hysteresis model: "
                         "export-mat writes an identified model")
    d = obj.to_dict()
    blocks = list(d["blocks"])
    del blocks[obj.kinds().index("hysteresis")]
    return model, {**d, "blocks": blocks}


def _cmd_predict(a: argparse.Namespace) -> int:
    from preisach.io import read_record, write_csv

    chain = _load_chain(a.model)
    rec = read_record(a.data, ["t", "u"])
    y = chain.predict(rec["t"], rec["u"])
    write_csv(a.output_path, {"t": rec["t"], "y": y})
    msg = f"wrote {a.output_path} ({len(y)} samples)"
    if "y" in rec:
        rmse = float(np.sqrt(np.mean((y - rec["y"]) ** 2)))
        msg += f"; RMSE against the record's y: {rmse:.6g}"
    print(msg)
    return 0


def _cmd_invert(a: argparse.Namespace) -> int:
    from preisach.chain import load, sample_period
    from preisach.io import read_record, write_csv
    from preisach.model import PreisachModel, PreisachWarning

    if a.lookahead is not None and a.method != "interpolated":
        raise UsageError(f"preisach invert: --lookahead is for --method interpolated, not {a.method} (see --help)")
    obj = load(a.model)
    if isinstance(obj, PreisachModel) and a.bandwidth is not None:
        raise UsageError("preisach invert: --bandwidth is for a chain with effects, not a single model (see --help)")
    rec = read_record(a.ref, ["t", "r"])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PreisachWarning)
        if isinstance(obj, PreisachModel):
            u = obj.invert(rec["r"], method=a.method, lookahead=a.lookahead)
            done = f", method {a.method}"
        else:
            fs = 1.0 / sample_period(rec["t"], "t")
            try:
                u, info = obj.invert(rec["r"], fs, method=a.method, bandwidth_hz=a.bandwidth, lookahead=a.lookahead,
                                     return_info=True)
            except ValueError as e:
                if str(e).startswith("blocks["):  # a block of the file that cannot be inverted
                    raise ValueError(f"{a.model}: {e}") from None
                raise
            done = (f"; chain inverse of {' -> '.join(obj.kinds())}, hysteresis method {a.method}, bandwidth "
                    f"{info.bandwidth_hz:.6g} Hz, preview {info.preview_s * 1e3:.4g} ms, latency {info.latency} "
                    "samples when streamed")
    write_csv(a.output_path, {"t": rec["t"], "u": u})
    print(f"wrote {a.output_path} ({len(u)} samples{done})")
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    return 0


def _cmd_simulate(a: argparse.Namespace) -> int:
    from preisach.io import read_record, write_csv
    from preisach.sim import Stage

    if (a.stage is None) == (a.preset is None):
        raise UsageError("preisach simulate: give either STAGE.json or --preset NAME (see --help)")
    chain = Stage.preset(a.preset) if a.preset is not None else _load_chain(a.stage)
    rec = read_record(a.input, ["t", "u"])
    try:
        y = chain.simulate(rec["t"], rec["u"])
    except ValueError as exc:  # e.g. a block the input's rate cannot run: name the record
        raise ValueError(f"{a.input}: {exc}") from None
    write_csv(a.output_path, {"t": rec["t"], "u": rec["u"], "y": y})
    fs = (rec["t"].size - 1) / (rec["t"][-1] - rec["t"][0]) if rec["t"].size > 1 else float("nan")
    print(f"wrote {a.output_path} ({len(y)} samples at the input's {fs:g} Hz)")
    return 0


def _cmd_diagnose(a: argparse.Namespace) -> int:
    from preisach.diagnose import run_cli

    return int(run_cli(a))


def _cmd_demo(a: argparse.Namespace) -> int:
    from preisach.demo import main_cli

    return main_cli(a.out, a.quick, a.no_plots)


def _cmd_import_mat(a: argparse.Namespace) -> int:
    from preisach.io import write_csv
    from preisach.matlab import list_channels, read_mat, sample_rate

    if a.list:
        for c in list_channels(a.file):
            d = c.data
            print(f"{c.index:4d}  {c.label:40s} {d.size:9d} samples  {d.min():.6g} .. {d.max():.6g}  ({c.source})")
        return 0
    if a.output_path is None or a.u is None:
        raise UsageError("preisach import-mat: give --u CHANNEL and -o RECORD.csv, or --list (see --help)")
    if a.t is not None and a.fs is not None:
        raise UsageError("preisach import-mat: give either --t or --fs, not both (see --help)")
    rec = read_mat(a.file, u=a.u, y=a.y, t=a.t, fs=a.fs)
    write_csv(a.output_path, rec)
    print(f"wrote {a.output_path} ({rec['u'].size} samples, columns {','.join(rec)}, "
          f"{sample_rate(rec['t']):.6g} Hz)")
    return 0


def _cmd_compare(a: argparse.Namespace) -> int:
    from preisach.comparison import compare, table

    chain = _load_chain(a.model)
    results = [compare(chain, path) for path in a.records]
    print(table(results))
    if a.json is not None:
        import json

        from preisach.io import write_text

        doc = {"model": a.model, "records": [r.to_dict() for r in results]}
        write_text(a.json, json.dumps(doc, indent=2, allow_nan=False) + "\n")
        print(f"wrote {a.json}")
    if a.plot is not None:
        from preisach.plots import plot_compare

        print(f"wrote {plot_compare(results, a.plot, title=a.model)}")
    return 0


def _cmd_export_mat(a: argparse.Namespace) -> int:
    from preisach.matlab import write_model_mat

    model, chain = _load_for_export(a.model)
    write_model_mat(a.output_path, model, chain)
    print(f"wrote {a.output_path}: weights ({model.n_h}x{model.n_h}, beta rows, alpha columns), levels "
          f"({model.n_h + 1}), offset, u_range, n_h, output ('{model.output}'), format")
    if chain is not None:
        names = [b["type"] for b in chain["blocks"]]
        print(f"and the struct chain with the blocks after the hysteresis ({', '.join(map(str, names)) or 'none'}): "
              "their parameters, which the MATLAB snippet in docs/guide/matlab.md does not evaluate")
    return 0


def _range(s: str) -> float:
    try:
        return float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {s!r}") from None


def _preflight(a: argparse.Namespace) -> None:
    """Check every output path and optional dependency before any work, so a long run
    does not fail at its end (errors name the option and the user's path)."""
    from preisach.io import check_writable

    for attr, (flag, is_dir) in OUTPUTS.items():
        path = getattr(a, attr, None)
        if path is not None:
            check_writable(path, flag, directory=is_dir)
    for attr, flag in (("plots", "--plots"), ("plot", "--plot")):
        if getattr(a, attr, None) is not None:
            from preisach.plots import HINT, available

            if not available():
                raise ValueError(f"{flag}: {HINT}")
    if a.command in ("import-mat", "export-mat"):
        import importlib.util

        from preisach.matlab import SCIPY_HINT

        if importlib.util.find_spec("scipy") is None:
            raise ValueError(SCIPY_HINT)


def _int_at_least(low: int) -> Callable[[str], int]:
    """An argparse type: an integer >= ``low``."""

    def parse(s: str) -> int:
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {s!r}") from None
        if v < low:
            raise argparse.ArgumentTypeError(f"must be >= {low}, got {v}")
        return v

    return parse


_positive_int = _int_at_least(1)
_nonneg_int = _int_at_least(0)


def build_parser() -> argparse.ArgumentParser:
    """The ``preisach`` argument parser with every subcommand."""
    p = _Parser(prog="preisach", description="Identify, invert, simulate and diagnose the Preisach "
                "hysteresis model of a piezo stage. Records are CSV with header t,u,y (or .npz).")
    from preisach import __version__
    from preisach.model import DIAGONAL_FLOOR

    p.add_argument("--version", action="version", version=f"preisach {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    def add(name: str, help: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=help, description=help, epilog=EXAMPLES.get(name), formatter_class=_Help)

    s = add("identify", "Identify a Preisach model from a record (t,u,y).")
    s.add_argument("data", metavar="DATA", help="record: CSV with header t,u,y or .npz")
    s.add_argument("--n-h", type=_positive_int, required=True, dest="n_h", metavar="N",
                   help="discretization level: cells per input axis (the paper uses 100)")
    s.add_argument("--range", type=_range, nargs=2, metavar=("LO", "HI"), default=None,
                   help="model range (default: the input range shrunk by 0.5%% at each end)")
    s.add_argument("--reg", type=float, default=0.0, help="smoothness regularization weight")
    # ('gradient' stays accepted so that it fails with the library's message naming what to use.)
    s.add_argument("--solver", choices=["auto", "active", "clarabel", "structured", "gradient"], default="auto",
                   metavar="{auto,active,clarabel,structured}",
                   help="QP solver; all exact, auto picks the fastest for the size (see docs/method/identification.md)")
    s.add_argument("--output-kind", dest="output", choices=["stepwise", "interpolated"], default="stepwise",
                   help="fit the stepwise (paper) or the interpolated (continuous) model")
    s.add_argument("--diagonal-floor", type=float, default=DIAGONAL_FLOOR, metavar="F",
                   help="lower bound on the diagonal (reversible) masses, as a fraction of the major loop's "
                        "average slope: keeps the continuous inverse from jumping at the reference's turns; "
                        "0 = plain non-negative least squares")
    s.add_argument("-o", dest="output_path", required=True, metavar="MODEL.json", help="where to write the model")
    s.set_defaults(func=_cmd_identify)

    s = add("predict", "Run a model (or a chain saved by diagnose) over a record; writes t,y.")
    s.add_argument("model", metavar="MODEL.json", help="a model or chain file")
    s.add_argument("data", metavar="DATA", help="record with columns t,u (y optional: RMSE is printed)")
    s.add_argument("-o", dest="output_path", required=True, metavar="OUT.csv", help="where to write t,y")
    s.set_defaults(func=_cmd_predict)

    s = add("compare", "Fit of a model on measured records, as MATLAB's compare: fit %, RMSE and max error "
            "per record, and a plot of measured against model with the residual.")
    s.add_argument("model", metavar="MODEL", help="a model or chain file (anything predict accepts)")
    s.add_argument("records", metavar="RECORD", nargs="+", help="records with columns t,u,y")
    s.add_argument("--plot", default=None, metavar="FILE.png",
                   help="draw measured vs model (over time and as a loop) and the residual per record "
                        "(needs preisach[plot])")
    s.add_argument("--json", default=None, metavar="OUT.json", help="write the figures as JSON")
    s.set_defaults(func=_cmd_compare)

    s = add("invert", "Input that makes the model (or the whole chain) follow a reference (t,r); writes t,u. "
                      "References beyond the reachable output are clipped and counted (one warning line).")
    s.add_argument("model", metavar="MODEL|CHAIN.json",
                   help="a model file, or a chain with effects (e.g. from diagnose --save-model): the chain "
                        "inverse (linear blocks inverted within --bandwidth, delays taken by preview)")
    s.add_argument("ref", metavar="REF.csv", help="reference with columns t,r")
    s.add_argument("--method", choices=["closest", "interpolated", "continuous"], default="continuous",
                   help="continuous: smooth input, no look-ahead (for a real stage; smooth at the reference's "
                        "turns too when the model was identified with identify's --diagonal-floor > 0); "
                        "closest: the paper's "
                        "per-sample closest match (a staircase); interpolated: the paper's Fig. 9 smoothing")
    s.add_argument("--lookahead", type=_nonneg_int, default=None, metavar="N",
                   help="preview samples for --method interpolated (default: the whole record; for a chain, "
                        "the inverter's latency, default its preview + 2000)")
    s.add_argument("--bandwidth", type=float, default=None, metavar="HZ",
                   help="a chain only: bandwidth of the linear inverse, below Nyquist (default: twice the fastest "
                        "lag of the chain's linear blocks, at most a tenth of the record's rate)")
    s.add_argument("-o", dest="output_path", required=True, metavar="U.csv", help="where to write t,u")
    s.set_defaults(func=_cmd_invert)

    s = add("simulate", "Run the plant simulator on an input record (t,u); writes t,u,y.")
    s.add_argument("stage", metavar="STAGE.json", nargs="?", default=None, help="a stage file (or use --preset)")
    s.add_argument("--preset", default=None, help="a built-in stage, e.g. 'paper'")
    s.add_argument("input", metavar="INPUT.csv", help="input record with columns t,u")
    s.add_argument("-o", dest="output_path", required=True, metavar="OUT.csv", help="where to write t,u,y")
    s.set_defaults(func=_cmd_simulate)

    s = add("diagnose", "Where the model and the stage disagree, which unmodelled effect causes it, "
            "and how far the gap shrinks once it is added (scored on holdout records).")
    s.add_argument("train", metavar="TRAIN", help="training record t,u,y (fits the baseline model)")
    s.add_argument("--holdout", action="append", required=True, metavar="H",
                   help="holdout record t,u,y (repeat for several); never used to fit anything")
    s.add_argument("--n-h", type=_positive_int, default=40, dest="n_h", metavar="N", help="baseline n_h")
    s.add_argument("--baseline", default=None, metavar="CHAIN.json",
                   help="a model (refitted with its effects), or a simulator kept as it is: the gap between it "
                        "and the records")
    s.add_argument("--refit-masses", dest="refit_masses", action="store_true",
                   help="with a simulator as --baseline: refit its hysteresis masses on TRAIN first")
    s.add_argument("--json", required=True, metavar="REPORT.json", help="write the full report here")
    s.add_argument("--save-model", dest="save_model", default=None, metavar="AUG.json",
                   help="write the augmented chain (runs with `preisach predict`)")
    s.add_argument("--plots", default=None, metavar="DIR", help="write PNG plots here (needs preisach[plot])")
    s.set_defaults(func=_cmd_diagnose)

    s = add("demo", "Run the paper's workflow on the simulated 'paper' stage: record, identify n_h=100, "
            "compensate 5 Hz / 50 Hz references with each inverse method, diagnose; writes figures, "
            "CSV records and report.md.")
    s.add_argument("--out", default="preisach-demo", metavar="DIR", help="output directory")
    s.add_argument("--quick", action="store_true", help="shorter records (a few seconds; for tests)")
    s.add_argument("--no-plots", dest="no_plots", action="store_true", help="skip the PNG figures")
    s.set_defaults(func=_cmd_demo)

    s = add("import-mat", "Convert a dSPACE/MATLAB capture (.mat, v4-v7) to a record CSV t,u[,y]. "
            "Channels by name or by the index --list prints. Needs SciPy: pip install 'preisach[mat]'.")
    s.add_argument("file", metavar="FILE.mat", help="the capture")
    s.add_argument("--list", action="store_true", help="print the channels (index, name, length, range) and exit")
    s.add_argument("--u", default=None, metavar="NAME|INDEX", help="input channel (DAC command)")
    s.add_argument("--y", default=None, metavar="NAME|INDEX", help="output channel (sensor); optional")
    s.add_argument("--t", default=None, metavar="NAME|INDEX",
                   help="time channel (default: the dSPACE capture's X axis)")
    s.add_argument("--fs", type=_range, default=None, metavar="HZ", help="sample rate, when there is no time channel")
    s.add_argument("-o", dest="output_path", default=None, metavar="RECORD.csv", help="where to write the record")
    s.set_defaults(func=_cmd_import_mat)

    s = add("export-mat", "Write a model (or a chain's hysteresis and blocks) as a MAT file for MATLAB: "
            "weights as an n_h x n_h matrix (beta rows, alpha columns), levels, offset, u_range. "
            "Needs SciPy: pip install 'preisach[mat]'.")
    s.add_argument("model", metavar="MODEL", help="a model or chain file")
    s.add_argument("-o", dest="output_path", required=True, metavar="MODEL.mat", help="where to write the MAT file")
    s.set_defaults(func=_cmd_export_mat)
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``preisach`` console script."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if not getattr(args, "command", None):
            parser.print_help()
            return 2
        _preflight(args)
        before = _existing_outputs(args)
        try:
            code = int(args.func(args))
        except KeyboardInterrupt:
            _remove_new_outputs(args, before)
            raise
        sys.stdout.flush()  # a closed pipe shows here, inside the handler, not at exit
        return code
    except UsageError as exc:
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return _closed_pipe()
    except (ValueError, OSError) as exc:
        print(f"preisach: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("preisach: interrupted", file=sys.stderr)
        return 130


def _one_line(exc: BaseException) -> str:
    """The message on one line: line breaks (from an argument or a file) shown escaped."""
    return str(exc).replace("\r", "\\r").replace("\n", "\\n")


def _existing_outputs(a: argparse.Namespace) -> set[str]:
    """The files (and directories) already present at the command's output paths."""
    from pathlib import Path

    found: set[str] = set()
    for attr, (_, is_dir) in OUTPUTS.items():
        path = getattr(a, attr, None)
        if path is None:
            continue
        p = Path(path)
        if p.exists():
            found.add(str(p))
            if is_dir and p.is_dir():
                found.update(str(q) for q in p.rglob("*"))
    return found


def _remove_new_outputs(a: argparse.Namespace, before: set[str]) -> None:
    """After Ctrl-C: remove what the interrupted command created at its output paths
    (files it wrote, directories it made), so no partial output is left. Files that
    were there before stay (each was either kept or replaced whole by an atomic write)."""
    import shutil
    from pathlib import Path

    for attr, (_, is_dir) in OUTPUTS.items():
        path = getattr(a, attr, None)
        if path is None:
            continue
        p = Path(path)
        new = [p] if str(p) not in before else (
            [q for q in p.rglob("*") if str(q) not in before] if is_dir and p.is_dir() else [])
        for q in sorted(new, key=lambda q: len(q.parts), reverse=True):
            if q.is_dir() and not q.is_symlink():
                shutil.rmtree(q, ignore_errors=True)
            elif q.exists() or q.is_symlink():
                q.unlink()


def _closed_pipe() -> int:
    """The reader of stdout went away (``preisach ... | head``): stop quietly with the
    shell's code for SIGPIPE, and point stdout at /dev/null so that the interpreter's
    final flush does not report the same error."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout without a file descriptor (captured in tests)
        pass
    return 141


if __name__ == "__main__":
    raise SystemExit(main())

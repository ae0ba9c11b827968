"""The ``uiest`` command line."""

from __future__ import annotations

import contextlib
import contextvars
import functools
import itertools
import math
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, ParamSpec, TypeVar

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeRemainingColumn
from rich.table import Table

from uiest import __version__, models
from uiest.analysis import analyse as analyse_model
from uiest.atomic import staged_folder, write_file, write_text
from uiest.box import as_vector
from uiest.checks import check_samples
from uiest.detectability import certify_delta_ioss, certify_reduced_model, certify_strong_detectability
from uiest.detectability.falsify import pairs_text
from uiest.errors import (
    BoundWarning,
    CertificationError,
    FailureWarning,
    ModelError,
    OptionError,
    UiestError,
)
from uiest.estimate import (
    ALL,
    ESTIMATORS,
    build_all,
    build_estimator,
    check_lag,
    default_prior,
    error_text,
    errors_against_truth,
    internal_error,
    recommended,
    run_estimators,
    write_estimates,
)
from uiest.estimators import UISE, StandardMHE, TwoStageUISE
from uiest.experiments import Scenario, provenance, run_study, write_report
from uiest.experiments.paper_study import study_of
from uiest.experiments.solver_bench import TABLE_HEADER, bench_window_solvers, table_row
from uiest.experiments.study_store import StudyStore
from uiest.experiments.sweep import Sweep, SweepProgress
from uiest.experiments.sweep import sweep as run_sweep
from uiest.json_text import json_text
from uiest.lock import folder_lock
from uiest.paths import writable_file, writable_folder
from uiest.plotting import plot_trajectory, save_figure
from uiest.progress_lines import ProgressLines
from uiest.results import read_record
from uiest.scales import data_scales
from uiest.simulate import check_steps
from uiest.simulate import simulate as run_simulation
from uiest.window.backends import BACKENDS
from uiest.window.size import check_horizon

__all__ = ["app", "main"]

app = typer.Typer(
    name="uiest",
    help="State estimation for nonlinear systems with unbounded unknown inputs.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
console = Console(markup=False)  # paths and messages may hold brackets
error_console = Console(stderr=True, markup=False)

Params = ParamSpec("Params")
Result = TypeVar("Result")
_COMMAND_EXITS: contextvars.ContextVar[contextlib.ExitStack] = contextvars.ContextVar("command_exits")
"""What the running command releases when it ends (the output folder it holds)."""

_SHOWN: contextvars.ContextVar[set[str]] = contextvars.ContextVar("shown_warnings")
"""The warning lines the running command has printed (each is printed once)."""


def _choice(value: str, allowed: Any, option: str) -> str:
    """``value`` if it is one of ``allowed``, else OptionError naming the option."""
    if value not in allowed:
        raise OptionError(f"{option}: expected one of {list(allowed)}, got {value!r}")
    return value


def _positive(value: int | None, option: str, *, allow_zero: bool = False) -> int | None:
    if value is not None and (value < 0 or (value == 0 and not allow_zero)):
        raise OptionError(f"{option}: expected an integer >= {0 if allow_zero else 1}, got {value}")
    return value


def _user_errors(command: Callable[Params, Result]) -> Callable[Params, Result]:
    """Turn uiest's typed errors into a one-line message and exit code 2, and warnings into plain message lines.

    Any other OSError (a file that could not be read or written) becomes one line naming the file and the
    cause, with exit code 1. The output folder the command holds (:func:`_output_folder`) is released at its end.
    """

    @functools.wraps(command)
    def wrapper(*args: Params.args, **kwargs: Params.kwargs) -> Result:
        with warnings.catch_warnings(), contextlib.ExitStack() as exits:  # restores the filters and showwarning
            warnings.showwarning = _show_warning
            token, shown = _COMMAND_EXITS.set(exits), _SHOWN.set(set())
            try:
                return command(*args, **kwargs)
            except UiestError as exc:
                _error_line(str(exc))
                raise typer.Exit(code=2) from None
            except OSError as exc:
                _error_line(f"{exc.filename}: {exc.strerror or exc}" if exc.filename else str(exc))
                raise typer.Exit(code=1) from None
            finally:
                _COMMAND_EXITS.reset(token)
                _SHOWN.reset(shown)

    return wrapper


def _error_line(text: str) -> None:
    error_console.print(f"error: {text}", style="bold red", highlight=False, soft_wrap=True, markup=False)


def _output_folder(folder: Path, option: str) -> Path:
    """Create ``folder``, check it is writable, and hold it against other runs until the command ends."""
    writable_folder(folder, option)
    return _COMMAND_EXITS.get().enter_context(folder_lock(folder, option))


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int, file: Any = None,
                  line: str | None = None) -> None:  # fmt: skip
    """A warning emitted during a command, as one message line on stderr (no source file or line), once per text.

    The same model or estimator is built many times in a command (a design's candidates, a fit's grid): its warning
    is printed the first time.
    """
    text = f"warning: {message}"
    shown = _SHOWN.get(None)  # None outside a command's context (another thread): printed as it comes
    if shown is None or text not in shown:
        if shown is not None:
            shown.add(text)
        error_console.print(text, style="yellow", highlight=False, soft_wrap=True, markup=False)


def _print_version(value: bool) -> None:
    """``--version``: print ``uiest <version>`` (the installed package's metadata) and exit."""
    if value:
        console.print(f"uiest {__version__}", highlight=False)
        raise typer.Exit()


@app.callback()
def root_options(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_print_version, is_eager=True, help="Print uiest's version and exit."),
    ] = False,
) -> None:
    """State estimation for nonlinear systems with unbounded unknown inputs."""


@app.command("models")
@_user_errors
def list_models() -> None:
    """List the registered models."""
    table = Table(title="registered models")
    for column in ("name", "nx", "nu", "nw", "nv", "ny", "dt", "description"):
        table.add_column(column)
    for name in models.names():
        entry = models.get(name)
        try:
            system = entry.build()
        except UiestError as exc:  # one broken model (a file registered this session) does not hide the others
            table.add_row(name, *"------", f"cannot be built: {exc}")
            continue
        sizes = (system.nx, system.nu, system.nw, system.nv, system.ny)
        table.add_row(name, *map(str, sizes), f"{system.dt:g} {system.time_unit}", entry.summary)
    console.print(table)


@app.command()
@_user_errors
def simulate(
    model: Annotated[str, typer.Argument(help="Registered model name (see `uiest models`) or a model file (.py).")],
    steps: Annotated[int | None, typer.Option(help="Number of steps K, in samples (default: the model's).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the measurement noise.")] = 0,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/simulate"),
    noise: Annotated[bool, typer.Option(help="Add the model's measurement noise.")] = True,
) -> None:
    """Simulate a registered model or a model file; write trajectory.csv and trajectory.png to OUT."""
    _positive(steps, "--steps", allow_zero=True)
    _output_folder(out, "--out")
    entry = models.load(model)
    system = entry.build()
    setup = entry.simulation()
    length = setup.steps if steps is None else check_steps(steps, system, "--steps", error=OptionError)
    with Progress(
        TextColumn(f"simulating {model}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task("simulate", total=max(length, 0))
        traj = run_simulation(
            system,
            setup.x0,
            length,
            u=setup.u,
            w=setup.w,
            v=setup.noise if noise else None,
            seed=seed,
            progress=lambda k: bar.update(task, completed=k),
        )
    csv_path, png_path = out / "trajectory.csv", out / "trajectory.png"
    units = {s.kind: s.units for s in system.signals}
    figure = plot_trajectory(traj, units)
    with staged_folder(out) as stage:
        write_file(stage / csv_path.name, traj.to_pandas().to_csv)
        save_figure(figure, stage / png_path.name)
    console.print(f"{system!r}: {traj.steps} steps, seed {seed}")
    console.print(f"wrote {csv_path} and {png_path}")


@app.command()
@_user_errors
def estimate(
    model: Annotated[
        str, typer.Argument(help="Registered model name, or a model file (.py with `system` or build()).")
    ],
    data: Annotated[
        Path, typer.Option(help="Measurements: .csv or .parquet with u and y columns named as the model's.")
    ],
    estimator: Annotated[
        list[str] | None,
        typer.Option(
            help="uise, delayed, two-stage, mhe, smooth, ekf, ukf or uio; repeat for several; 'all': every one the "
            "model admits (default: the one `uiest analyse` recommends)."
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/estimate"),
    lag: Annotated[
        int,
        typer.Option(
            help="Also deliver x[k-lag] from each window estimator (filters have no window); lag in samples (0: none)."
        ),
    ] = 0,
    horizon: Annotated[
        int | None,
        typer.Option(
            help="Largest window N of a design, in samples (default 30, or up to 60 where only a longer window "
            "certifies); N when the model does not certify (20)."
        ),
    ] = None,
    w_variance: Annotated[
        float | None,
        typer.Option(
            help="Variance of one step of the unknown input's random walk, w[k+1] - w[k] (ekf, ukf; smooth: of its "
            "increments; mhe: of its disturbance w[k]), as a multiple of (w's scale)^2, the square of the model's "
            "nominal size of each unknown input: 1 is a step whose standard deviation is one scale; the run prints "
            "it in w's unit^2 per step (default: the likelihood's maximum on --data)."
        ),
    ] = None,
    x0: Annotated[
        str | None,
        typer.Option(
            help="Prior of x[0] in the states' units, comma separated in the model's state order "
            "(default: the model's)."
        ),
    ] = None,
) -> None:
    """Estimate states and unknown inputs from measurements.

    Writes estimates_<estimator>.csv, estimates.png and manifest.json (the record and model files, how each
    estimator's weights were chosen) to --out, and removes the estimates_*.csv an earlier run left there.
    """
    _positive(lag, "--lag", allow_zero=True)
    _positive(horizon, "--horizon")
    check_lag(lag, horizon)
    if w_variance is not None and not 0 < w_variance < math.inf:
        raise OptionError(f"--w-variance: expected a positive finite number, got {w_variance}")
    _output_folder(out, "--out")
    entry = models.load(model)
    system = entry.build()
    if horizon is not None:
        check_horizon(horizon, "--horizon", system)
    record = read_record(data, system)
    prior = _prior_option(x0, entry, system)
    system = data_scales(system, prior, record=record)  # where X's width is no scale: the data's magnitudes
    options = {"lag": lag, "horizon": horizon, "w_variance": w_variance, "record": record}
    with console.status("building estimators") as status:
        built, notes, skipped = _build_estimators(status, estimator or [], entry, system, prior, options)
        status.update(f"estimating over {record.steps} steps")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", BoundWarning)
            warnings.simplefilter("always", FailureWarning)
            results = run_estimators(built, record, prior)
    steps = f"{record.steps} step{'s' * (record.steps != 1)}"
    title = f"{entry.name}: {steps} from {data}; {_prior_text(system, record, prior, x0, entry)}"
    _print_estimates(title, system, record, results, notes, skipped)
    for caught_warning in caught:  # as messages, not as Python warnings with a source line
        if issubclass(caught_warning.category, (BoundWarning, FailureWarning)):
            error_console.print(f"warning: {caught_warning.message}", style="yellow", soft_wrap=True, markup=False)
        else:
            warnings.warn_explicit(caught_warning.message, caught_warning.category, caught_warning.filename,
                                   caught_warning.lineno)  # fmt: skip
    given = {"lag": lag, "horizon": horizon, "w_variance": w_variance, "x0": x0}
    manifest = _estimate_manifest(model=model, data=data, prior=prior, estimators=list(results),
                                  weights={kind: notes[kind] for kind in results}, not_run=skipped,
                                  one_step_ahead=[kind for kind, result in results.items() if result.one_step_ahead],
                                  options=given)  # fmt: skip
    written = write_estimates(out, system, record, results, manifest=manifest)
    console.print(f"wrote {', '.join(str(p) for p in written)}", markup=False, soft_wrap=True)


def _estimate_manifest(*, model: str, data: Path, prior: Any, **run: Any) -> dict[str, Any]:
    """``uiest estimate``'s manifest.json: the model and the record (path, SHA-256), the prior, the estimators.

    Also how each estimator's weights were chosen (the table's column), those not run (with why), the options, and the
    call (:func:`uiest.experiments.provenance.stamp`).
    """
    path = str(Path(model).resolve()) if model.endswith(".py") else model
    return {
        "command": "estimate",
        "model": {"name": path, "sha256": provenance.model_digest(model)},
        "data": {"path": str(data.resolve()), "sha256": provenance.file_digest(data)},
        "prior_x0": [float(value) for value in prior],
        **run,
        **provenance.stamp(),
    }


def _prior_option(x0: str | None, entry: Any, system: Any) -> Any:
    """``--x0`` as a vector (nx,) in the states' units, or the model's prior when it is not given."""
    if x0 is None:
        return default_prior(entry, system)
    try:
        values = [float(part) for part in x0.split(",")]
    except ValueError:
        raise OptionError(f"--x0: expected {system.nx} comma-separated numbers, got {x0!r}") from None
    return as_vector(values, system.nx, "--x0")


def _prior_text(system: Any, record: Any, prior: Any, x0: str | None, entry: Any) -> str:
    """Which prior of x[0] the estimators start from, where it came from, and whether it is the record's truth."""
    import numpy as np  # where a command needs it: `uiest --version` stays light

    source = (
        "--x0"
        if x0 is not None
        else ("the model's setup()" if entry.setup is not None else "X's centre, 0 where unbounded")
    )
    values = ", ".join(f"{name} {value:.4g}" + (f" {unit}" if unit not in ("", "-") else "")
                       for name, value, unit in zip(system.x.names, prior, system.x.units, strict=True))  # fmt: skip
    text = f"prior x[0]: {values} (from {source})"
    truth = record.x[0] if record.x is not None and len(record.x) else None
    if truth is not None and np.all(np.isfinite(truth)) and np.allclose(prior, truth, rtol=1e-9, atol=0.0):
        text += ", the record's true x[0]: the errors leave out a start from a wrong prior"
        text += "" if x0 is not None else " (give --x0)"
    return text


RUN_DESIGNS_ITS_OWN = (
    "The estimator run below chooses its own weights and window for accuracy under noise: its mu, N and guarantee "
    "are the ones in the table, not the analysis's"
)
"""Said after the analysis's recommendation: the analysis's design (its mu, N and bound) is not the one run."""


def _build_estimators(
    status: Any, kinds: list[str], entry: Any, system: Any, prior: Any, options: dict[str, Any]
) -> tuple[dict[str, Any], dict[str, str], dict[str, str]]:
    """The estimators asked for (none: the recommended one; ``all``: every one the model admits).

    Returns ``(built, notes, skipped)``: per kind the estimator, the note on its weights, and why it was skipped. One
    that the model does not admit, or that cannot be built on the record, is skipped and the others run; where none
    can be, the first refusal is the error.
    """
    if not kinds:
        status.update("analysing the model")
        kind, why = recommended(system, prior, options["horizon"])
        console.print(f"recommended: {kind}: {why} (`uiest analyse` shows the whole analysis). {RUN_DESIGNS_ITS_OWN}",
                      markup=False, highlight=False, soft_wrap=True)  # fmt: skip
        kinds = [kind]
    unknown = [kind for kind in kinds if kind not in (*ESTIMATORS, ALL)]
    if unknown:
        raise OptionError(f"--estimator: expected one of {[*ESTIMATORS, ALL]}, got {unknown[0]!r}")
    if ALL in kinds:
        status.update("building every estimator the model admits")
        return build_all(entry, system, prior, **options)
    built: dict[str, Any] = {}
    notes: dict[str, str] = {}
    skipped: dict[str, str] = {}
    refused: list[Exception] = []
    defects: list[Exception] = []
    for kind in dict.fromkeys(kinds):
        status.update(f"building {kind}")
        try:
            built[kind], notes[kind] = build_estimator(kind, entry, system, prior, **options)
        except (ModelError, CertificationError, OptionError) as exc:  # not admitted, or not built on this record
            if type(exc) not in (ModelError, CertificationError, OptionError):
                raise
            refused.append(type(exc)(f"--estimator {kind}: {exc}"))
            skipped[kind] = str(exc)
        except Exception as exc:  # a defect met by one estimator: the others still run, and the error is named
            if len(kinds) == 1:
                raise
            defects.append(exc)
            skipped[kind] = internal_error(exc)
    if not built:  # none to run: the first refusal is the command's error (a defect's own, where none was refused)
        raise (refused or defects)[0] from None
    return built, notes, skipped


def _print_estimates(
    title: str, system: Any, record: Any, results: dict[str, Any], notes: dict[str, str], skipped: dict[str, str]
) -> None:
    """The estimators' table (weights, RMSE against the truth when the data hold it, guarantee) and step health."""
    rmse = errors_against_truth(record, results)
    table = Table(title=title)
    for column in ("estimator", "weights", "RMSE vs truth, per state", "guarantee"):
        table.add_column(column)
    for kind, result in results.items():
        error = error_text(system, rmse[kind], lagged=kind == "delayed" and result.x_lag is not None)
        label = f"{kind} (one step ahead: x[k] from y[..k-1])" if result.one_step_ahead else kind
        table.add_row(label, notes[kind], error, str(result.guarantee))
    console.print(table)
    for kind, why in skipped.items():
        console.print(f"{kind}: not run ({why})", markup=False, highlight=False, soft_wrap=True)
    console.print(_health_table(results))


def _health_table(results: dict[str, Any]) -> Table:
    """Step counts of each estimator's run (:meth:`uiest.results.EstimationResult.counts`)."""
    table = Table(title="steps: failed, IPOPT fallbacks, estimates at a side of X, held inputs, propagated by the "
                        "model alone")  # fmt: skip
    for column in ("estimator", "failed", "fallback", "at X's side", "window at X's side", "held input", "propagated"):
        table.add_column(column)
    for kind, result in results.items():
        counts = result.counts()
        names = result.names.get("x") or ()
        per_state = ", ".join(f"{name} {counts[f'at_bound_{name}']}" for name in names if counts[f"at_bound_{name}"])
        at_side = f"{counts['at_bound']} ({per_state})" if per_state else str(counts["at_bound"])
        table.add_row(kind, str(counts["failures"]), str(counts["fallbacks"]), at_side,
                      str(counts["window_at_bound"]), str(counts["held"]), str(counts["propagated"]))  # fmt: skip
    return table


@app.command()
@_user_errors
def certify(
    model: Annotated[str, typer.Argument(help="Registered model name (see `uiest models`) or a model file (.py).")],
    out: Annotated[Path, typer.Option(help="JSON file for the certificates.")] = Path("out/certify/certificates.json"),
    structure: Annotated[str, typer.Option(help="P of the delta-IOSS certificate: full or identity.")] = "full",
    verify: Annotated[int, typer.Option(help="Random pairs for each certificate's sampled verification.")] = 100_000,
    seed: Annotated[int, typer.Option(help="Seed of the samples and the verification.")] = 0,
) -> None:
    """Certify a registered model or a model file: strong detectability, reduced-order e-IOSS, delta-IOSS."""
    check_samples(verify, "--verify")
    if structure not in ("full", "identity"):
        raise OptionError(f"--structure: expected full or identity, got {structure!r}")
    _positive(seed, "--seed", allow_zero=True)
    writable_file(out, "--out")
    entry = models.load(model)
    system = entry.build()
    parameters = entry.jacobian_parameters() if entry.jacobian_parameters is not None else None

    def strong() -> tuple[Any, Callable[[Any], Any]]:
        cert = certify_strong_detectability(system, parameters=parameters, seed=seed)
        return cert, lambda c: UISE(system, certificate=c)

    def reduced() -> tuple[Any, Callable[[Any], Any]]:
        assert entry.reduction is not None
        red = entry.reduction()
        return certify_reduced_model(red, seed=seed), lambda c: TwoStageUISE(red, certificate=c)

    def delta() -> tuple[Any, Callable[[Any], Any]]:
        return certify_delta_ioss(system, structure=structure, seed=seed), lambda c: StandardMHE(system, certificate=c)

    jobs: list[tuple[str, Callable[[], tuple[Any, Callable[[Any], Any]]]]] = [("strong detectability", strong)]
    if entry.reduction is not None:
        jobs.append(("reduced-order e-IOSS", reduced))
    jobs.append((f"delta-IOSS (P {structure})", delta))
    records: list[dict[str, Any]] = []
    with console.status("certifying") as status:
        for label, job in jobs:
            status.update(f"certifying: {label}")
            start = time.perf_counter()
            try:
                cert, estimator = job()
            except UiestError as exc:  # e.g. matching fails: this certificate does not apply, the others may
                records.append({"certificate": label, "certified": False, "status": "not applicable",
                                "reason": str(exc), "time_s": time.perf_counter() - start})  # fmt: skip
                continue
            check = cert.verify(verify, seed=seed)
            records.append({"certificate": label, **cert.to_dict(), "verify_worst_ratio": check.worst_ratio,
                            "verify_pairs": check.pairs_used, "verify_pairs_drawn": check.pairs_drawn,
                            "time_s": time.perf_counter() - start,
                            "guarantee": _estimator_guarantee(cert, estimator)})  # fmt: skip
    table = Table(title=f"certificates of {model}")
    table.add_column("")
    for record in records:
        table.add_column(record["certificate"])
    cells = [_certificate_cells(record, system.x.names, system.x.units) for record in records]
    for i, name in enumerate(ROWS):
        table.add_row(name, *[column[i] for column in cells])
    console.print(table)
    for record in records:
        console.print(f"{record['certificate']}: {record['reason']}", highlight=False, soft_wrap=True, markup=False)
        guarantee = record.get("guarantee")
        if guarantee is not None:  # None: the certificate does not hold, so no estimator is built from it
            line = f"  {guarantee['estimator']} with N = min horizon, {guarantee['theorem']}: {guarantee['text']}"
            console.print(line, highlight=False, soft_wrap=True, markup=False)
    write_text(out, json_text({"model": model, "certificates": records}, default=float))
    console.print(f"wrote {out}")


@app.command()
@_user_errors
def analyse(
    model: Annotated[str, typer.Argument(help="Registered model name (see `uiest models`) or a model file (.py).")],
    max_horizon: Annotated[int, typer.Option(help="Longest estimator window N considered, in samples.")] = 60,
    json_file: Annotated[Path | None, typer.Option("--json", help="Also write the analysis as JSON.")] = None,
) -> None:
    """Which estimator suits a model, and why: structure, zeros, near-zeros, certificates, recommendation."""
    _positive(max_horizon, "--max-horizon")
    if json_file is not None:
        writable_file(json_file, "--json")
    system = models.load(model).build()
    check_horizon(max_horizon, "--max-horizon", system)
    with console.status(f"analysing {system.name}"):
        analysis = analyse_model(system, max_horizon=max_horizon)
    console.print(analysis.text(), highlight=False, soft_wrap=True, markup=False)
    if json_file is not None:
        write_text(json_file, json_text({"model": model, **analysis.to_dict()}, default=float))
        console.print(f"wrote {json_file}")


ROWS = ("status", "rate (mu, eta)", "smallest rate", "cond(P) (c_x)", "gains (scaled)", "noise gain per step",
        "min horizon", "guarantee at min horizon", "cover", "search: max ratio", "verify: max ratio",
        "time")  # fmt: skip


def _estimator_guarantee(cert: Any, estimator: Callable[[Any], Any]) -> dict[str, Any] | None:
    """The guarantee of the estimator ``cert`` designs, with N = its min horizon (None when not certified)."""
    if not cert.certified:
        return None
    try:
        built = estimator(cert)
    except UiestError as exc:
        return {"estimator": "-", "theorem": "-", "applies": False, "verdict": "none", "text": f"none: {exc}"}
    return {"estimator": built.estimator_name, **built.guarantee.to_dict()}


def _certificate_cells(record: dict[str, Any], state_names: tuple[str, ...], units: tuple[str, ...]) -> list[str]:
    """Table cells of one certificate record, in the order of ``ROWS``."""
    time_s = f"{record['time_s']:.2f} s"
    found = record.get("falsification")
    search = "-" if not found else (f"{found['worst_ratio']:.4g} ({pairs_text(found['pairs_scored'], found['pairs'])}, "
                                    f"{found['local_searches']} local)")  # fmt: skip
    if not record["certified"]:
        return [record["status"], "-", _number(record.get("rate_min")), "-", "-", "-", "-", "-",
                record.get("cover_kind") or "-", search, "-", time_s]  # fmt: skip
    kind = record["kind"]
    cond = record["c_x"] if kind == "reduced_eioss" else record["condition_scaled"]
    noise = "-"
    if kind == "strong_detectability":
        gains = f"sigma_y {record['sigma_y']:.3g}\nsigma_v {record['sigma_v']:.3g}"
        noise = "\n".join(f"{n}: {g:.3g} {u}".rstrip() for n, g, u in zip(state_names, record["noise_gain"], units,
                                                                            strict=True))  # fmt: skip
    elif kind == "reduced_eioss":
        gains = f"c_y {record['c_y']:.3g}\nc_v {record['c_v']:.3g}\nc_gamma {record['c_gamma']:.3g}"
    else:
        gains = "Q_w, Q_v, R: see JSON"
    cover = record["cover_kind"]
    ratio = f"{record['verify_worst_ratio']:.4g} ({pairs_text(record['verify_pairs'], record['verify_pairs_drawn'])})"
    guarantee = record.get("guarantee")
    verdict = "-" if guarantee is None else f"{guarantee['estimator']}: {guarantee.get('verdict', 'none')}"
    return [record["status"], _number(record["rate"]), _number(record["rate_min"]), f"{cond:.3g}", gains, noise,
            str(record["min_horizon"]), verdict, cover, search, ratio, time_s]  # fmt: skip


def _number(value: Any) -> str:
    return "-" if value is None or value != value else f"{value:.6g}"


@app.command()
@_user_errors
def reproduce(
    study: Annotated[
        str,
        typer.Argument(
            help="A model with a study: crop-growth (the paper's), or a model file with study() "
            "(ignored with --scenario)."
        ),
    ] = "crop-growth",
    quick: Annotated[bool, typer.Option(help="2 runs instead of 20 (a check in under 2 minutes).")] = False,
    runs: Annotated[int | None, typer.Option(help="Monte Carlo runs per case.")] = None,
    steps: Annotated[int | None, typer.Option(help="Steps K per run, in samples.")] = None,
    solver: Annotated[
        str,
        typer.Option(
            help="Window solver backend (ipopt: the paper's, so Table 1 compares; gn: 4-15x less CPU per sample)."
        ),
    ] = "ipopt",
    scenario: Annotated[Path | None, typer.Option(help="A scenario TOML file (any registered model).")] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            help="Output folder (default out/<study>); finished runs are kept in OUT/runs, and a rerun "
            "with the same folder computes only the others."
        ),
    ] = None,
    workers: Annotated[int | None, typer.Option(help="Processes running the runs (default: all cores).")] = None,
) -> None:
    """Run a model's study (default: the paper's crop-growth study): figures, Table 1, report.md; or a scenario file."""
    _choice(solver, BACKENDS, "--solver")
    _positive(runs, "--runs")
    _positive(steps, "--steps")
    _positive(workers, "--workers")
    if scenario is not None:
        setting = Scenario.from_toml(scenario)
    else:
        try:
            entry = models.load(study)
        except OptionError as exc:
            raise OptionError(f"study: {exc}") from None
        make_study = study_of(entry)
        if make_study is None:
            raise OptionError(
                f"study: the model {study!r} has no study(); give one in its file, or --scenario FILE.toml"
            )
        setting = make_study()
        if not isinstance(setting, Scenario):
            raise ModelError(f"study: {study!r}'s study() returned {type(setting).__name__}, expected a Scenario")
    try:
        setting = setting.with_overrides(runs=2 if quick and runs is None else runs, steps=steps)
    except OptionError as exc:  # e.g. the scenario's settle does not fit the given --steps
        given = " ".join(
            f"{flag} {value}" for flag, value in (("--runs", runs), ("--steps", steps)) if value is not None
        )
        raise OptionError(f"{given}: {exc}" if given else str(exc)) from None
    folder = out if out is not None else Path("out") / setting.name
    _output_folder(folder, "--out")
    store = StudyStore(folder / "runs", setting, solver)  # each finished run, kept for a rerun with this --out
    runs_total = setting.runs * len(setting.cases)
    stored = sum(store.load(*task) is not None for task in store.stored())  # a damaged file is set aside now
    start = time.perf_counter()
    try:
        with contextlib.ExitStack() as stack:
            if console.is_terminal:
                columns = (SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                           TimeRemainingColumn())  # fmt: skip
                bar = stack.enter_context(Progress(*columns, console=console))
                task = bar.add_task(setting.name, total=runs_total * len(setting.estimators),
                                    completed=stored * len(setting.estimators))  # fmt: skip
                progress = lambda label: bar.update(task, advance=1, description=label)  # noqa: E731
            else:  # a log or a pipe: periodic lines on stderr, one count per (case, run) with all its estimators
                lines, calls = ProgressLines(setting.name, runs_total, done=stored), itertools.count(1)

                def progress(label: str) -> None:
                    if next(calls) % len(setting.estimators) == 0:
                        lines.advance()

            result = run_study(setting, solver=solver, workers=workers, progress=progress, store=store.folder)
        manifest = write_report(result, folder, wall_time=time.perf_counter() - start)
    except KeyboardInterrupt:
        message = (f"interrupted: {len(store.stored())} of {runs_total} runs are stored in {store.folder}; the same "
                   "command with the same --out computes only the others")  # fmt: skip
        error_console.print(message, markup=False, soft_wrap=True)
        raise typer.Exit(code=130) from None
    console.print((folder / "table1.md").read_text(), highlight=False, markup=False)
    files = manifest["files"]
    assert isinstance(files, list)  # write_report's manifest lists the files it wrote
    console.print(f"wrote {len(files)} files to {folder} (report: {folder / 'report.md'})", markup=False)
    if (result.runs["error"] != "").all():
        error_console.print("error: every estimator raised on every run; see the report's Failures", markup=False)
        raise typer.Exit(code=1)


@app.command()
@_user_errors
def sweep(
    design: Annotated[Path, typer.Argument(help="Sweep TOML: [scenario] and [sweep] (grid, random, ranges).")],
    out: Annotated[Path, typer.Option(help="Output folder (results are appended; re-running resumes).")] = Path(
        "out/sweep"
    ),
    workers: Annotated[int | None, typer.Option(help="Worker processes (default: all cores).")] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address, or 'local' for a LocalCluster.")
    ] = None,
    solver: Annotated[str, typer.Option(help="Default window solver backend (ipopt, gn, rti, gn-riccati).")] = "gn",
    retry_failed: Annotated[bool, typer.Option(help="Compute again the stored tasks that recorded an error.")] = False,
) -> None:
    """Run a Monte Carlo sweep over scenario parameters (local processes or a Dask cluster)."""
    _choice(solver, BACKENDS, "--solver")
    _positive(workers, "--workers")
    plan = Sweep.from_toml(design)  # read before the output folder is made: a bad file leaves no folder behind
    _output_folder(out, "--out")
    total = len(plan.tasks(solver))
    last = SweepProgress(0, 0, 0, 0)
    lines: ProgressLines | None = None  # without a terminal: periodic lines on stderr
    with contextlib.ExitStack() as stack:
        if console.is_terminal:
            columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
            bar = stack.enter_context(Progress(*columns, console=console))
            task = bar.add_task("sweep", total=total)

        def update(state: SweepProgress) -> None:
            nonlocal last, lines
            last = state
            finished = state.skipped + state.done  # lost tasks are neither: the bar stops short of the total
            if not console.is_terminal:
                if lines is None:
                    lines = ProgressLines("sweep", total, done=state.skipped, unit="tasks")
                lines.advance(finished - lines.done, lost=state.lost - lines.lost)
                return
            bar.update(task, completed=finished,
                       description=f"done {state.done} (skipped {state.skipped}), failed {state.failed}, "
                       f"lost {state.lost}, remaining {state.remaining}")  # fmt: skip

        try:
            results = run_sweep(plan, out, workers=workers, scheduler=scheduler, solver=solver, progress=update,
                                retry_failed=retry_failed)  # fmt: skip
        except KeyboardInterrupt:
            message = (f"interrupted: the tasks that finished are stored in {out / 'runs'}; the same command with "
                       "the same --out computes only the others")  # fmt: skip
            error_console.print(message, markup=False, soft_wrap=True)
            raise typer.Exit(code=130) from None
    keys = results["key"].nunique() if not results.empty else 0
    failed = int(results.groupby("key")["error"].apply(lambda e: (e != "").any()).sum()) if keys else 0
    console.print(f"{keys} of {total} tasks stored ({failed} with an error), {last.lost} lost this run; "
                  f"{len(results)} rows in {out / 'results.parquet'}, summary {out / 'summary.csv'}", markup=False,
                  soft_wrap=True)  # fmt: skip
    if last.lost:
        model_lost = last.lost_to_model_change
        why = (": the model file changed during the run" if model_lost == last.lost else
               f", {model_lost} because the model file changed during the run" if model_lost else "")  # fmt: skip
        error_console.print(f"error: {last.lost} task{'s were' if last.lost != 1 else ' was'} not computed{why} (see "
                            f"{out / 'lost_tasks.log'}); run again", markup=False, soft_wrap=True)  # fmt: skip
        raise typer.Exit(code=1)
    if keys == 0 or bool((results["error"] != "").all()):  # no estimator of any task gave a result
        error_console.print("error: every task failed; see the 'error' column of results.parquet")
        raise typer.Exit(code=1)


@app.command()
@_user_errors
def bench(
    quick: Annotated[bool, typer.Option(help="100 samples, N = 30 unless -N is given (under a minute).")] = False,
    json_file: Annotated[Path | None, typer.Option("--json", help="Write the records as JSON.")] = None,
    horizon: Annotated[
        list[int] | None,
        typer.Option("--horizon", "-N", help="Window length in samples (repeat for several; default 10 30 100 300)."),
    ] = None,
    estimator: Annotated[
        list[str] | None,
        typer.Option(help="'UISE', 'two-stage UISE' or 'standard MHE' (repeat for several; default all)."),
    ] = None,
) -> None:
    """Window solver backends (ipopt, gn, rti, gn-riccati) x estimators x N on the noisy crop scenario."""
    if json_file is not None:
        writable_file(json_file, "--json")

    printed: list[dict[str, object]] = []
    caps: set[tuple[object, object]] = set()

    def report(record: dict[str, object]) -> None:
        if not printed:  # the header once the arguments were accepted
            title = "window solvers, noisy crop scenario (ms per sample after N_used warm-up samples)"
            console.print(title, highlight=False)
            console.print(TABLE_HEADER, highlight=False, soft_wrap=True)
        capped = (record["estimator"], record["N"])
        if record["N_used"] < record["N"] and capped not in caps:  # type: ignore[operator]
            caps.add(capped)
            line = (
                f"{record['estimator']}: N={record['N']} capped at its information horizon {record['N_used']} "
                "(older cost terms fall below double precision)"
            )
            console.print(line, highlight=False, soft_wrap=True)
        printed.append(record)
        console.print(table_row(record), highlight=False, soft_wrap=True)

    records = bench_window_solvers(
        quick=quick,
        horizons=tuple(horizon) if horizon else None,
        estimators=tuple(estimator) if estimator else None,
        report=report,
    )
    if json_file is not None:
        write_text(json_file, json_text(records))
        console.print(f"wrote {json_file}")


def main() -> None:
    """Entry point for ``python -m uiest``."""
    app()

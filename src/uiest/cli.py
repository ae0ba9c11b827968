"""The ``uiest`` command line."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from uiest import models
from uiest.errors import UiestError

app = typer.Typer(
    name="uiest",
    help="State estimation for nonlinear systems with unbounded unknown inputs.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console()
error_console = Console(stderr=True)

F = TypeVar("F", bound=Callable[..., Any])


def _user_errors(command: F) -> F:
    """Turn uiest's typed errors into a one-line message and exit code 2."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except UiestError as exc:
            error_console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


@app.command("models")
@_user_errors
def list_models() -> None:
    """List the registered models."""
    table = Table(title="registered models")
    for column in ("name", "nx", "nu", "nw", "nv", "ny", "dt", "description"):
        table.add_column(column)
    for name in models.names():
        entry = models.get(name)
        system = entry.build()
        sizes = (system.nx, system.nu, system.nw, system.nv, system.ny)
        table.add_row(name, *map(str, sizes), f"{system.dt:g} {system.time_unit}", entry.summary)
    console.print(table)


@app.command()
@_user_errors
def simulate(
    model: Annotated[str, typer.Argument(help="Registered model name (see `uiest models`).")],
    steps: Annotated[int | None, typer.Option(help="Number of steps K (default: the model's).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the measurement noise.")] = 0,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("out/simulate"),
    noise: Annotated[bool, typer.Option(help="Add the model's measurement noise.")] = True,
) -> None:
    """Simulate a registered model; write trajectory.csv and trajectory.png to OUT."""
    from uiest.plotting import plot_trajectory, save_figure
    from uiest.simulate import simulate as run_simulation

    entry = models.get(model)
    system = entry.build()
    setup = entry.setup()
    length = setup.steps if steps is None else steps
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
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "trajectory.csv"
    traj.to_pandas().to_csv(csv_path)
    units = {s.kind: s.units for s in system.signals}
    png_path = save_figure(plot_trajectory(traj, units), out / "trajectory.png")
    console.print(f"{system!r}: {traj.steps} steps, seed {seed}")
    console.print(f"wrote {csv_path} and {png_path}")


@app.command()
@_user_errors
def reproduce(
    study: Annotated[str, typer.Argument(help="Study to reproduce (crop-growth).")] = "crop-growth",
) -> None:
    """Reproduce the paper's crop-growth study (arrives with issue 6; not available yet)."""
    error_console.print(
        f"`uiest reproduce {study}` is not available yet: it arrives with the estimators (issues 3-6). "
        "Today `uiest simulate crop-growth` simulates the paper's model.",
        highlight=False,
        soft_wrap=True,
    )
    raise typer.Exit(code=1)


def main() -> None:
    """Entry point for ``python -m uiest``."""
    app()

"""Progress display: an iteration table for solves (a callback), a progress bar for long runs
(receding-horizon resolves, sweeps)."""

from __future__ import annotations

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)


class IterationTable:
    """A solve callback that prints one row per iteration: iteration, cost, ε, μ, seconds and
    the phase split (``hydroilqr.solve(task, callbacks=[IterationTable()])``)."""

    def __init__(self, console: Console | None = None, prefix: str = ""):
        self.console = console or Console(highlight=False)
        self.prefix = prefix
        self.header = False

    def __call__(self, info) -> None:
        if not self.header:
            self.console.print(
                f"{self.prefix}[bold]{'iter':>4} {'cost':>12} {'eps':>8} {'reg':>8} "
                f"{'sec':>7}  rollout/deriv/backward/linesearch[/bold]"
            )
            self.header = True
        ph = info.phases
        mark = "" if info.accepted else "  (no step)"
        self.console.print(
            f"{self.prefix}{info.iteration:>4} {info.cost:>12.6g} {info.eps:>8.3g} "
            f"{info.mu:>8.1e} {info.seconds:>7.3f}  {ph['rollout']:.3f}/{ph['derivatives']:.3f}/"
            f"{ph['backward_pass']:.3f}/{ph['line_search']:.3f}{mark}"
        )


class _Bar:
    """A rich progress bar named ``label`` over ``total`` steps with an info field and the
    time left; a context manager."""

    def __init__(self, label: str, total: int, console: Console | None = None):
        self.progress = Progress(
            TextColumn(f"[bold]{label}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[info]}"),
            TimeElapsedColumn(),
            TextColumn("left"),
            TimeRemainingColumn(),
            console=console,
        )
        self.label = label
        self.total = total
        self.id = None

    def __enter__(self):
        self.progress.__enter__()
        self.id = self.progress.add_task(self.label, total=self.total, info="")
        return self

    def __exit__(self, *exc):
        return self.progress.__exit__(*exc)


class ResolveProgress(_Bar):
    """A progress bar over receding-horizon resolves with time left; use as a context manager
    and pass ``update`` as the ``on_resolve`` callback."""

    def __init__(self, total: int):
        super().__init__("resolves", total)

    def update(self, done: int, total: int, sol) -> None:
        info = f"it={sol.iterations} cost={sol.final_cost:.4g}"
        self.progress.update(self.id, completed=done, info=info)


class SearchProgress(_Bar):
    """A progress bar over a sampling search's iterations with the best cost so far; use as
    a context manager and pass ``update`` as the search's ``on_iteration`` callback."""

    def __init__(self, total: int, console: Console | None = None):
        super().__init__("search", total, console)

    def update(self, info: dict) -> None:
        text = f"best {info['best_cost']:.5g}, median {info['median']:.4g}"
        if info.get("restart"):
            text = f"restart {info['restart']}: {text}"
        if info.get("failed"):
            text += f", {info['failed']} failed"
        self.progress.update(self.id, completed=info["iteration"] + 1, info=text)

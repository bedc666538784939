"""Progress display for long runs (receding-horizon resolves, sweeps)."""

from __future__ import annotations

from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)


class ResolveProgress:
    """A progress bar over receding-horizon resolves with time left; use as a context manager
    and pass ``update`` as the ``on_resolve`` callback."""

    def __init__(self, total: int):
        self.progress = Progress(
            TextColumn("[bold]resolves"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[info]}"),
            TimeElapsedColumn(),
            TextColumn("left"),
            TimeRemainingColumn(),
        )
        self.total = total
        self.id = None

    def __enter__(self):
        self.progress.__enter__()
        self.id = self.progress.add_task("resolves", total=self.total, info="")
        return self

    def __exit__(self, *exc):
        return self.progress.__exit__(*exc)

    def update(self, done: int, total: int, sol) -> None:
        info = f"it={sol.iterations} cost={sol.final_cost:.4g}"
        self.progress.update(self.id, completed=done, info=info)

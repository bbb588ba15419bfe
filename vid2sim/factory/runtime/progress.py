"""Live ingest progress: one line per clip (stage, status, elapsed) and totals."""

from __future__ import annotations

import time
from typing import Optional

from rich.console import Console
from rich.live import Live
from rich.table import Table

from vid2sim.factory.runtime.orchestrator import ClipState

_STYLE = {"pending": "dim", "running": "yellow", "done": "green", "failed": "red"}


class IngestProgress:
    """Context manager; pass `update` as the orchestrator's `on_update`."""

    def __init__(self, clip_ids: list[str], stage_names: list[str], console: Optional[Console] = None,
                 enabled: bool = True) -> None:
        self.rows = {cid: ("pending", "", "") for cid in clip_ids}
        self.stage_names = stage_names
        self.t0 = time.perf_counter()
        self.console = console or Console(stderr=True)
        self.enabled = enabled
        self._live: Optional[Live] = None

    def __enter__(self) -> "IngestProgress":
        if self.enabled:
            self._live = Live(self._table(), console=self.console, refresh_per_second=4, transient=False)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live is not None:
            self._live.update(self._table())
            self._live.__exit__(*exc)

    def update(self, state: ClipState) -> None:
        if state.status == "failed":
            detail = f"{state.reason}"
        elif state.status == "running":
            detail = f"{self._position(state.stage)} {state.stage}"
        else:
            detail = state.stage if state.status == "done" else ""
        self.rows[state.clip_id] = (state.status, state.stage, detail)
        if self._live is not None:
            self._live.update(self._table())

    def _position(self, stage: str) -> str:
        if stage in self.stage_names:
            return f"[{self.stage_names.index(stage) + 1}/{len(self.stage_names)}]"
        return ""

    def _table(self) -> Table:
        elapsed = time.perf_counter() - self.t0
        table = Table(title=f"vid2sim ingest ({elapsed:,.0f} s)", expand=False)
        table.add_column("clip")
        table.add_column("status")
        table.add_column("stage / reason")
        for cid, (status, _stage, detail) in self.rows.items():
            style = _STYLE.get(status, "")
            table.add_row(cid, f"[{style}]{status}[/{style}]", detail)
        counts = {k: sum(1 for s, _, _ in self.rows.values() if s == k) for k in _STYLE}
        table.caption = "  ".join(f"{k}: {v}" for k, v in counts.items())
        return table

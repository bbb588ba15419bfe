"""Read-only DuckDB SQL over the manifest rows (`vid2sim registry query`).

The query runs in a fresh in-memory DuckDB that sees only two relations: `scenes` (every row)
and `latest` (newest version per scene). After they are registered, external access is switched
off and the configuration locked, so no file, URL, extension, ATTACH or COPY can be reached; only
one SELECT statement is accepted; memory, threads, time, returned rows and returned bytes are
capped. The result streams in small batches and stops at `max_bytes` (default: the memory limit),
so `--memory 64MB` never hands back more than 64 MB of rows (`ResultTooLarge`).
"""

from __future__ import annotations

import math
import re
import threading
from dataclasses import dataclass
from typing import Optional

import pyarrow as pa

from vid2sim.registry.errors import RegistryError


class QueryError(RegistryError):
    """The SQL is not a single read-only SELECT, or DuckDB rejected or aborted it."""


class BadQueryLimit(QueryError, ValueError):
    """A query cap is out of range (memory size unreadable or too small, zero rows, ...)."""


class ResultTooLarge(QueryError):
    """The query's result holds more bytes than the cap."""


MIN_MEMORY = 16 * 10**6  # DuckDB needs some working memory for even a trivial plan
BATCH_ROWS = 64  # rows per streamed result batch (the byte cap is checked after each)
_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12,
          "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}
_SIZE_RE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([a-z]*)\s*$", re.IGNORECASE)


def parse_size(text: str) -> int:
    """'512MB' / '2GiB' / '1048576' -> bytes; BadQueryLimit on anything else."""
    m = _SIZE_RE.match(str(text))
    unit = m.group(2).lower() if m else ""
    if not m or unit not in _UNITS:
        raise BadQueryLimit(f"memory limit {text!r}: expected a size such as 64MB, 512MiB or 2GB")
    return int(float(m.group(1)) * _UNITS[unit])


@dataclass(frozen=True)
class QueryLimits:
    """Caps for one query (defaults suit a manifest of 100k rows on a laptop)."""

    memory: str = "512MB"  # DuckDB's memory limit, and the default cap on returned bytes
    threads: int = 2
    timeout_s: float = 60.0
    max_rows: int = 10_000  # rows returned; more are cut off and reported
    max_bytes: Optional[int] = None  # bytes returned (Arrow buffers); None: the memory limit

    def __post_init__(self) -> None:
        if self.memory_bytes < MIN_MEMORY:
            raise BadQueryLimit(f"memory limit {self.memory!r}: must be at least 16MB")
        if self.threads < 1 or self.max_rows < 1:
            raise BadQueryLimit(f"threads {self.threads} and max_rows {self.max_rows} must be >= 1")
        if not (math.isfinite(self.timeout_s) and self.timeout_s > 0):
            raise BadQueryLimit(f"timeout {self.timeout_s!r}: must be a positive number of seconds")
        if self.max_bytes is not None and self.max_bytes < 1:
            raise BadQueryLimit(f"max_bytes {self.max_bytes}: must be >= 1")

    @property
    def memory_bytes(self) -> int:
        return parse_size(self.memory)

    @property
    def result_bytes(self) -> int:
        return self.max_bytes if self.max_bytes is not None else self.memory_bytes


LATEST_VIEW = ("CREATE VIEW latest AS SELECT * FROM scenes "
               "QUALIFY row_number() OVER (PARTITION BY scene_id ORDER BY version DESC) = 1")


def _connect(scenes: pa.Table, limits: QueryLimits):
    import duckdb

    con = duckdb.connect(config={"memory_limit": f"{limits.memory_bytes}B", "threads": limits.threads,
                                 "autoinstall_known_extensions": False, "autoload_known_extensions": False})
    con.register("scenes", scenes)
    con.execute(LATEST_VIEW)
    con.execute("SET enable_external_access = false")
    con.execute("SET lock_configuration = true")
    return con


def _check_select(con, sql: str) -> None:
    import duckdb

    try:
        statements = con.extract_statements(sql)
    except duckdb.Error as e:
        raise QueryError(f"query failed: {e}") from None
    kinds = [s.type for s in statements]
    if kinds != [duckdb.StatementType.SELECT]:
        names = ", ".join(k.name for k in kinds) or "nothing"
        raise QueryError(f"query must be one read-only SELECT statement (got {names})")


def run_query(scenes: pa.Table, sql: str, limits: QueryLimits = QueryLimits()) -> tuple[pa.Table, bool]:
    """(at most `limits.max_rows` result rows, whether more rows were cut off)."""
    import duckdb

    con = _connect(scenes, limits)
    timer = threading.Timer(limits.timeout_s, con.interrupt)
    try:
        _check_select(con, sql)
        timer.start()
        table = _fetch_capped(con.sql(sql).limit(limits.max_rows + 1), limits.result_bytes)
    except duckdb.InterruptException:
        raise QueryError(f"query stopped after {limits.timeout_s:g} s (time limit)") from None
    except duckdb.Error as e:
        raise QueryError(f"query failed: {str(e).splitlines()[0]}") from None
    finally:
        timer.cancel()
        con.close()
    return table.slice(0, limits.max_rows), table.num_rows > limits.max_rows


def _fetch_capped(rel, max_bytes: int) -> pa.Table:
    """The relation's rows as one Arrow table, streamed; ResultTooLarge once past `max_bytes`."""
    reader = (getattr(rel, "to_arrow_reader", None) or rel.fetch_record_batch)(BATCH_ROWS)
    batches, total, rows = [], 0, 0
    for batch in reader:
        total += batch.nbytes
        if total > max_bytes:
            raise ResultTooLarge(f"query result exceeds the cap of {max_bytes:,} bytes after {rows:,} rows "
                                 "(--memory sets it): select fewer or narrower columns, or add a LIMIT")
        batches.append(batch)
        rows += batch.num_rows
    return pa.Table.from_batches(batches, schema=reader.schema)

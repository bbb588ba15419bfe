"""Read-only DuckDB SQL over the manifest rows (`vid2sim registry query`).

The query runs in a fresh in-memory DuckDB that sees only two relations: `scenes` (every row)
and `latest` (newest version per scene). After they are registered, external access is switched
off and the configuration locked, so no file, URL, extension, ATTACH or COPY can be reached; only
one SELECT statement is accepted; memory, threads, time and returned rows are capped.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import pyarrow as pa

from vid2sim.registry.errors import RegistryError


@dataclass(frozen=True)
class QueryLimits:
    """Caps for one query (defaults suit a manifest of 100k rows on a laptop)."""

    memory: str = "512MB"
    threads: int = 2
    timeout_s: float = 60.0
    max_rows: int = 10_000  # rows returned; more are cut off and reported


class QueryError(RegistryError):
    """The SQL is not a single read-only SELECT, or DuckDB rejected or aborted it."""


LATEST_VIEW = ("CREATE VIEW latest AS SELECT * FROM scenes "
               "QUALIFY row_number() OVER (PARTITION BY scene_id ORDER BY version DESC) = 1")


def _connect(scenes: pa.Table, limits: QueryLimits):
    import duckdb

    con = duckdb.connect(config={"memory_limit": limits.memory, "threads": limits.threads,
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
        rel = con.sql(sql).limit(limits.max_rows + 1)
        fetch = getattr(rel, "to_arrow_table", None) or rel.arrow  # duckdb 2.x / 1.x
        table = fetch()
    except duckdb.InterruptException:
        raise QueryError(f"query stopped after {limits.timeout_s:g} s (time limit)") from None
    except duckdb.Error as e:
        raise QueryError(f"query failed: {str(e).splitlines()[0]}") from None
    finally:
        timer.cancel()
        con.close()
    return table.slice(0, limits.max_rows), table.num_rows > limits.max_rows

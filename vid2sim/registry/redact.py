"""Source URI redaction: what of a source address may be stored, logged or printed.

An allow-list, not a deny-list: a URI keeps its scheme, host, port and path, and only the query
parameters in SAFE_QUERY_PARAMS; user info (user:password@), every other query parameter
(signatures, SAS tokens, client secrets, refresh tokens, access/secret/account keys, under any
name) and the fragment (#access_token=... in OAuth redirects) are dropped. The ingest applies it
before a URI reaches its cache, a log line or an error; `Registry.add` refuses a bundle whose
`source.uri` still carries anything it would drop.
"""

from __future__ import annotations

import contextlib
import logging
import re
import threading
from typing import Iterator

# Both select an object version (S3, GCS) and grant nothing.
SAFE_QUERY_PARAMS = frozenset({"versionId", "generation"})
# Schemes that name data the factory generates itself (never fetched; the query holds generation
# parameters such as the seed): kept whole.
GENERATED_SCHEMES = frozenset({"synthetic"})
_URI_RE = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*://")


def redact_uri(uri: str) -> str:
    """`uri` reduced to scheme, host, port, path and the allowed query parameters (see module
    doc). Not a URI (a local path): unchanged."""
    from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

    if not _URI_RE.match(uri):
        return uri
    scheme = uri.split("://", 1)[0]
    if scheme.lower() in GENERATED_SCHEMES:
        return uri
    try:
        parts = urlsplit(uri)
        host = parts.hostname or ""
        port = parts.port
    except ValueError:  # unparsable host or port: nothing of the address is kept
        return f"{scheme}://[unparsable address]"
    if ":" in host:  # IPv6 literal
        host = f"[{host}]"
    netloc = host + (f":{port}" if port is not None else "")
    query = urlencode([(k, v) for k, v in parse_qsl(parts.query, keep_blank_values=True)
                       if k in SAFE_QUERY_PARAMS])
    return urlunsplit((parts.scheme, netloc, parts.path, query, ""))


def scrub(text: str, uri: str) -> str:
    """`text` (e.g. a backend's error message) with `uri` and every part of it that redaction
    drops (user info, query values, fragment) replaced: safe to print."""
    from urllib.parse import parse_qsl, unquote, urlsplit

    safe = redact_uri(uri)
    out = text.replace(uri, safe)
    if safe == uri:
        return out
    secrets: set[str] = set()
    try:
        parts = urlsplit(uri)
        secrets.update(x for x in (parts.username, parts.password, parts.query, parts.fragment) if x)
        secrets.update(v for k, v in parse_qsl(parts.query, keep_blank_values=True) if k not in SAFE_QUERY_PARAMS)
        secrets.update(v for _, v in parse_qsl(parts.fragment, keep_blank_values=True))
        secrets.add(parts.netloc.rpartition("@")[0])
    except ValueError:
        secrets.add(uri.split("://", 1)[1])
    for s in sorted((s for s in secrets | {unquote(s) for s in secrets} if len(s) >= 3), key=len, reverse=True):
        out = out.replace(s, "***")
    return out


_FETCHING: dict[int, str] = {}  # id -> a URI whose secrets must not reach a log record
_LOCK = threading.Lock()
_installed = False


def _install_log_scrubber() -> None:
    """Wrap the log record factory once: while `scrubbed_logs` is active for a URI, every log
    record (a library's debug line quoting the URL, from any thread) is scrubbed of its secrets."""
    global _installed
    with _LOCK:
        if _installed:
            return
        previous = logging.getLogRecordFactory()

        def factory(*args, **kwargs) -> logging.LogRecord:
            record = previous(*args, **kwargs)
            if not _FETCHING:
                return record
            uris = list(_FETCHING.values())

            def clean(text: str) -> str:
                for uri in uris:
                    text = scrub(text, uri)
                return text

            try:
                msg = record.getMessage()
            except Exception:  # noqa: BLE001 - a malformed record is the logging module's to report
                return record
            if clean(msg) != msg:
                record.msg, record.args = clean(msg), ()
            if record.exc_info:  # a traceback quoting the URL: keep it as scrubbed text only
                record.exc_text = clean(logging.Formatter().formatException(record.exc_info))
                record.exc_info = None
            if record.stack_info:
                record.stack_info = clean(record.stack_info)
            return record

        logging.setLogRecordFactory(factory)
        _installed = True


@contextlib.contextmanager
def scrubbed_logs(uri: str) -> Iterator[None]:
    """Within the block, no log record carries a secret part of `uri` (see `scrub`)."""
    if redact_uri(uri) == uri:
        yield
        return
    _install_log_scrubber()
    key = object()
    with _LOCK:
        _FETCHING[id(key)] = uri
    try:
        yield
    finally:
        with _LOCK:
            _FETCHING.pop(id(key), None)

"""What the flows print on the terminal.

The contract of every ``python -m flows`` command: progress goes to stdout,
and stderr carries at most one line, ``error: <file>: <field>: expected …``.
Prefect's console handler writes to stderr and prints full tracebacks when a
flow fails; :func:`quiet_prefect_console` moves it to stdout and shortens any
exception to one line.  The Prefect API handler is left alone, so the UI still
has the full traceback of an unexpected failure.
"""
from __future__ import annotations

import logging
import sys

from nnsf.errors import exception_line


class NoTracebackFormatter(logging.Formatter):
    """Wraps a formatter; an exception shows as ``(Type: message)``, never a traceback.

    The wrapped formatter never sees ``exc_info``/``exc_text``/``stack_info``,
    and they are put back afterwards because other handlers (the Prefect API
    handler) receive the same record and should keep the traceback.
    """

    def __init__(self, inner: logging.Formatter | None):
        super().__init__()
        self.inner = inner or logging.Formatter()

    def format(self, record: logging.LogRecord) -> str:
        saved = record.exc_info, record.exc_text, record.stack_info
        exc = record.exc_info[1] if record.exc_info else None
        record.exc_info = record.exc_text = record.stack_info = None
        try:
            text = self.inner.format(record)
        finally:
            record.exc_info, record.exc_text, record.stack_info = saved
        if exc is not None and str(exc) not in text:
            text += f" ({exception_line(exc)})"
        return text


def quiet_prefect_console() -> None:
    """Send Prefect's console logging to stdout without tracebacks.

    Call after ``import prefect`` (which configures logging).  Python warnings
    are routed through logging too, so a library's DeprecationWarning does not
    land on stderr either.
    """
    from prefect.logging.handlers import PrefectConsoleHandler

    seen: set[int] = set()
    for logger in [logging.getLogger()] + [
        logging.getLogger(name) for name in list(logging.root.manager.loggerDict)
    ]:
        for handler in getattr(logger, "handlers", ()):
            if isinstance(handler, PrefectConsoleHandler) and id(handler) not in seen:
                seen.add(id(handler))
                handler.setStream(sys.stdout)
                handler.console.file = sys.stdout  # the rich console keeps its own stream
                if not isinstance(handler.formatter, NoTracebackFormatter):
                    handler.setFormatter(NoTracebackFormatter(handler.formatter))
    logging.captureWarnings(True)


def error_line(message: str) -> None:
    """Print the one error line on stderr."""
    print(f"error: {message}", file=sys.stderr, flush=True)

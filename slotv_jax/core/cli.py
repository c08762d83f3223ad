"""One error style for every command line (:ref:`concepts-commands`).

Wrap each command's ``main`` with :func:`command`::

    from slotv_jax import cli

    @cli.command
    def main(argv: Sequence[str] | None = None) -> int:
        args = parser.parse_args(argv)
        fileio.check_output_dir(args.out, ...)       # before any work
        if args.n < 1:
            raise cli.InputError(f"--n: expected an integer >= 1, got {args.n}")
        ...
        return 0

    if __name__ == "__main__":
        raise SystemExit(main())

An *input error* — :class:`InputError`, any ``ValueError`` (the project's readers and
checks raise ValueError with a message naming the argument, file, line and field;
:class:`slotv_jax.core.fileio.OutputError` is one), or an ``OSError`` about a path the user
gave (file not found, is a directory, permission denied, ...) — prints one line
``error: MESSAGE`` on stderr, with no traceback, and exits with code 2; so does a flag that
the parser itself refuses (an unknown flag, a value not of its type or choices), when the
parser is an :class:`ArgumentParser` of this module. Anything else is a bug and keeps its
traceback. Set ``SLOTV_JAX_TRACEBACK=1`` to see the traceback of an input error too.

Ctrl-C (``KeyboardInterrupt``) prints one line, ``interrupted``, and exits with code 130
(128 + SIGINT, as a shell reports it), with no traceback; a command that resumes
(``@command(resumes=True)``: rerunning it keeps what it finished) says so: ``interrupted;
rerun the same command to resume``. Nothing is left half-written: every file goes to a
temporary name that is removed on the way out (:func:`slotv_jax.core.fileio.atomic_write`).
A second Ctrl-C while the process exits ends it at once. A Ctrl-C is never lost: where a
library's bare ``except:`` swallows the ``KeyboardInterrupt`` (JAX has a few right after a
compilation, where a Ctrl-C pressed during a long compile surfaces), the command still
ends as interrupted, at the latest when its work is done (:func:`keep_interrupts`); a
second Ctrl-C stops it there and then.

>>> @command
... def main(argv=None):
...     raise InputError("--in x.npz: no such file")
>>> main()                       # doctest: +SKIP
error: --in x.npz: no such file            (on stderr; SystemExit(2))
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import gc
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence

EXIT_INPUT_ERROR = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT: what a shell reports for a command ended by Ctrl-C
INTERRUPTED = "interrupted"
INTERRUPTED_RESUMES = "interrupted; rerun the same command to resume"


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose own refusals (an unknown flag, a value not of the
    flag's type or choices, a missing one) are one line ``error: MESSAGE (see PROG
    --help)``, exit code 2, like every other input error, instead of the usage block;
    ``--help`` is unchanged. Every command's parser is one (its sub-commands' too)."""

    def error(self, message: str):
        print(f"error: {message} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(EXIT_INPUT_ERROR)


class InputError(ValueError):
    """Bad input from the user: the message names the argument, file, line or field."""


def message(exc: BaseException) -> str:
    """The one-line text of an input error (an OSError as ``PATH: reason``)."""
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        return f"{exc.filename}: {exc.strerror.lower()}"
    text = str(exc).strip()
    if isinstance(exc, KeyError) or not text:
        text = f"{type(exc).__name__}: {text}"
    return text


def is_input_error(exc: BaseException) -> bool:
    """True for the errors that :func:`command` reports in one line."""
    return isinstance(
        exc,
        ValueError  # includes InputError, OutputError, JSONDecodeError, UnicodeDecodeError
        | FileNotFoundError
        | FileExistsError
        | IsADirectoryError
        | NotADirectoryError
        | PermissionError,
    )


def fail(exc: BaseException) -> None:
    """Print ``error: ...`` for ``exc`` on stderr and exit with code 2."""
    print(f"error: {message(exc)}", file=sys.stderr, flush=True)
    raise SystemExit(EXIT_INPUT_ERROR) from None


def interrupted(*, resumes: bool | str = False) -> None:
    """Print the one line of a Ctrl-C on stderr and exit with code 130.

    A second Ctrl-C from here on ends the process at once (the default handler), so that
    a slow exit (threads, flushes) can still be cut short.
    """
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
    if isinstance(resumes, str):
        line = f"{INTERRUPTED}; {resumes}"
    else:
        line = INTERRUPTED_RESUMES if resumes else INTERRUPTED
    # at a terminal the cursor stands after the echoed ^C or on a progress bar: a new line
    lead = "\n" if sys.stderr.isatty() else ""
    print(lead + line, file=sys.stderr, flush=True)
    raise SystemExit(EXIT_INTERRUPTED) from None


_PENDING = threading.Event()  # a Ctrl-C that no command has answered yet


def _on_sigint(signum, frame) -> None:
    _PENDING.set()
    raise KeyboardInterrupt


@contextlib.contextmanager
def keep_interrupts() -> Iterator[threading.Event]:
    """While inside, SIGINT raises ``KeyboardInterrupt`` as usual and is also remembered
    until the ``with`` block ends: yields the event that is set once one came, so that a
    command whose Ctrl-C was swallowed on its way up still ends as interrupted. Only in
    the main thread and where SIGINT has Python's default handler (a process started with
    SIGINT ignored, as a shell's background job, keeps ignoring it)."""
    ours = (
        threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    )
    if ours:
        signal.signal(signal.SIGINT, _on_sigint)
    try:
        yield _PENDING
    finally:
        if ours:  # (a command run inside another leaves the outer one's state alone)
            _PENDING.clear()
            signal.signal(signal.SIGINT, signal.default_int_handler)


def _cut_short(unraisable) -> None:
    """``sys.unraisablehook`` while an interrupted command's frames are freed: a Ctrl-C
    can land inside any object's ``__init__`` (tqdm's, between creating a bar and setting
    its position), and that half-built object's finaliser then fails ("Exception ignored
    in: tqdm.__del__ ... no attribute 'pos'"). Those tracebacks are about objects the
    interrupt cut short, not errors of the command, so they are not printed."""


def command(
    main: Callable[..., int] | None = None, *, resumes: bool | str = False
) -> Callable[..., int]:
    """Decorate a command's ``main(argv)``: input errors become ``error: ...`` and exit 2;
    Ctrl-C becomes ``interrupted`` and exit 130 (``resumes=True``: the command resumes
    when rerun, and the line says so; a string says how, ``"rerun with --resume to
    continue"``). Use as ``@command`` or ``@command(resumes=True)``."""
    if main is None:
        return functools.partial(command, resumes=resumes)

    @functools.wraps(main)
    def wrapped(argv: Sequence[str] | None = None, *args, **kwargs) -> int:
        hook = sys.unraisablehook
        with keep_interrupts() as pending:
            try:
                code = main(argv, *args, **kwargs)
                if not pending.is_set():
                    return code
                # a Ctrl-C came and was swallowed before it could be raised again
            except KeyboardInterrupt:
                if os.environ.get("SLOTV_JAX_TRACEBACK"):
                    raise
                sys.unraisablehook = _cut_short  # from here until the frames are collected
            except Exception as e:
                if not is_input_error(e) or os.environ.get("SLOTV_JAX_TRACEBACK"):
                    raise
                fail(e)
                raise  # unreachable: fail() exits
        # Ctrl-C, outside the except clause: the interrupt's frames are gone, so what they
        # held (progress bars, open files) is closed before the one line is printed
        try:
            gc.collect()
        finally:
            sys.unraisablehook = hook
        interrupted(resumes=resumes)
        raise AssertionError("unreachable: interrupted() exits")

    wrapped.resumes = resumes
    return wrapped

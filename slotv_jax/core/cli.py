"""One error style for every command line (SPEC §11).

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
``error: MESSAGE`` on stderr, with no traceback, and exits with code 2, as argparse
does for a bad flag. Anything else is a bug and keeps its traceback. Set
``SLOTV_JAX_TRACEBACK=1`` to see the traceback of an input error too.

>>> @command
... def main(argv=None):
...     raise InputError("--in x.npz: no such file")
>>> main()                       # doctest: +SKIP
error: --in x.npz: no such file            (on stderr; SystemExit(2))
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable, Sequence

EXIT_INPUT_ERROR = 2


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


def command(main: Callable[..., int]) -> Callable[..., int]:
    """Decorate a command's ``main(argv)``: input errors become ``error: ...`` and exit 2."""

    @functools.wraps(main)
    def wrapped(argv: Sequence[str] | None = None, *args, **kwargs) -> int:
        try:
            return main(argv, *args, **kwargs)
        except Exception as e:
            if not is_input_error(e) or os.environ.get("SLOTV_JAX_TRACEBACK"):
                raise
            fail(e)
            raise  # unreachable: fail() exits

    return wrapped

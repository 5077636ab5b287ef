"""The ``hil`` command line: one entry point, sub-commands registered by the modules that own them.

Every sub-command module exposes ``register(subparsers)`` which adds its parsers and sets
``func`` (``func(args) -> int`` exit code). Exit codes: 0 success, 1 the checked thing is
false (a verdict, a failed check), 2 usage or configuration error.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback

from hil.errors import HilError

# Order is the order in `hil --help`.
COMMAND_MODULES = (
    "hil.config_cmd",
    "hil.thruster_profile_cmd",
    "hil.dbc_cmd",
    "hil.lcm_cmd",
    "hil.vcan",
    "hil.uml",
    "hil.netns",
    "hil.thresholds_cmd",
    "hil.run",
    "hil.panel",
    "hil.console",
    "hil.flood",
    "hil.runall",
    "hil.report",
    "hil.record_cmd",
    "hil.bench",
    "hil.soak",
    "hil.campaign.cli",
)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2 (argparse: usage + message)
        print(f"error: {self.prog}: {message} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(2)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("thruster-hil")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "(not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="hil", description="Thruster hardware-in-the-loop emulator.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a bad argument (2, its one line printed)
        return int(exc.code or 0)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except HilError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a path the user gave that cannot be read or written
        if args.debug:
            traceback.print_exc()
        where = exc.filename if exc.filename is not None else args.command
        print(f"error: {where}: expected a path that can be used here, got "
              f"{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

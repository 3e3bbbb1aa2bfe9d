"""Argument types and output checks shared by the command-line modules.

A list option refuses an empty list and a value listed twice (a repeated size would count one
cell's images twice); an output is checked before any work, so a bad ``--out`` costs nothing.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import socket
import sys
import time
from collections.abc import Iterable
from pathlib import Path

from bench.common.atomic import check_writable
from bench.common.executor import CONNECT_TIMEOUT_S, EXECUTORS
from bench.common.run_folder import check_not_input, check_not_owned, check_out_path
from scenes.validation import MAX_SEED, FieldError, shown_value

#: Where a command's run folder goes without ``--out``: not ``results/``, which holds the
#: committed results (the Makefile's targets write there by ``--out``), so a user's run on a
#: fresh clone is neither refused by nor mixed into a committed one. Ignored by git.
RUNS = Path("runs")


def _distinct(option: str, text: str, values: tuple) -> tuple:
    if not values:
        raise argparse.ArgumentTypeError(f"{option}: needs at least one value")
    repeated = next((v for i, v in enumerate(values) if v in values[:i]), None)
    if repeated is not None:
        raise argparse.ArgumentTypeError(
            f"{option}: {text!r}: {repeated!r} is listed twice; list each value once"
        )
    return values


def float_list(option: str):
    """argparse type: comma-separated finite numbers, each once; a bad one is refused naming
    ``option``."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(",") if v.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{option}: {text!r} is not a comma-separated list of numbers"
            ) from None
        if not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"{option}: {text!r}: every number must be finite")
        return _distinct(option, text, values)

    return parse


#: ``--psf-scale band``: the camera profile's own band (:meth:`scenes.profile.Band.psf_levels`).
BAND = "band"


def psf_scales_option(text: str) -> tuple[float, ...] | str:
    """argparse type of ``--psf-scale``: ``band`` or a comma-separated list of factors."""
    return BAND if text.strip() == BAND else float_list("--psf-scale")(text)


def name_list(option: str):
    """argparse type: comma-separated names, each once (at least one)."""

    def parse(text: str) -> tuple[str, ...]:
        return _distinct(option, text, tuple(v.strip() for v in text.split(",") if v.strip()))

    return parse


def distinct(option: str, values, text: str | None = None) -> tuple:
    """``values`` as a tuple, refused (argparse error quoting ``text``, the option's value)
    when empty or when one repeats."""
    return _distinct(option, ",".join(map(str, values)) if text is None else text, tuple(values))


def seed(text: str) -> int:
    """argparse type of ``--seed``: an integer in 0..2**32 - 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seed: {text!r} is not an integer") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"--seed: {value}: allowed range is 0..{MAX_SEED}")
    return value


#: The largest integer option: every integer up to it is exact as a float, in which the limits
#: (bench.cli.limits) weigh each option's cost.
MAX_INTEGER = 2**53


def integer(text: str) -> int:
    """argparse type of the integer options (counts, sizes, indices): an integer of at most
    :data:`MAX_INTEGER` in magnitude; each option's own range is checked after."""
    value = int(text)  # ValueError: argparse says "invalid integer value"
    if abs(value) > MAX_INTEGER:
        raise argparse.ArgumentTypeError(
            f"{shown_value(value)}: at most {MAX_INTEGER} in magnitude"
        )
    return value


#: The Linux ioctl reading a file's attribute flags, and its immutable and append-only flags.
_FS_IOC_GETFLAGS, _FS_IMMUTABLE_FL, _FS_APPEND_FL = 0x80086601, 0x10, 0x20


def check_path_name(path: Path, field: str = "out") -> None:
    """A path the file system can hold and reach: every name within the file system's limit
    (255 bytes on most), no dangling symbolic link or link loop on the way; FieldError naming
    ``field`` otherwise (the system would refuse it only when the work is done)."""
    parent = next((p for p in path.absolute().parents if os.path.isdir(p)), Path("/"))
    try:
        name_max = os.pathconf(parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    for part in path.parts:
        if len(os.fsencode(part)) > name_max:
            raise FieldError(
                field, f"{part[:16]}...: a name of {len(os.fsencode(part))} bytes; the file "
                f"system allows {name_max}",
            )  # fmt: skip
    for at in (path, *path.parents):  # the deepest part that exists says whether it resolves
        try:
            os.stat(at)  # follows links: a loop, a file on the way, a long path show here
            return
        except (FileNotFoundError, NotADirectoryError):  # the folder check says more
            if os.path.islink(at):
                raise FieldError(
                    field, f"{at}: a symbolic link to {os.readlink(at)}, which does not exist; "
                    "remove it or name another path",
                ) from None  # fmt: skip
        except OSError as exc:  # ELOOP, ENOTDIR, EACCES, ENAMETOOLONG
            raise FieldError(field, f"{at}: {exc.strerror}") from None


def _check_replaceable(path: Path, field: str) -> None:
    """An existing output file flagged immutable or append-only (``chattr +i``) cannot be
    replaced, even by root: refused now rather than after the work."""
    import fcntl

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return  # absent, or unreadable: the folder's check or the write says more
    try:
        flags = fcntl.ioctl(fd, _FS_IOC_GETFLAGS, b"\0" * 8)
        value = int.from_bytes(flags[:4], sys.byteorder)
    except OSError:  # a file system without attribute flags
        return
    finally:
        os.close(fd)
    if value & (_FS_IMMUTABLE_FL | _FS_APPEND_FL):
        kind = "immutable" if value & _FS_IMMUTABLE_FL else "append-only"
        raise FieldError(
            field, f"{path}: the file is {kind} (chattr); it cannot be replaced: "
            "clear the flag or name another file",
        )  # fmt: skip


def check_out_folder(path: Path | str, field: str = "out", inputs: Iterable[Path] = ()) -> Path:
    """An output folder that is the command's own to write (made later, not now): not an
    existing file or special file, not a dangling symbolic link, writable, not inside another
    run's files (:func:`~bench.common.run_folder.check_not_owned`) and none of ``inputs``;
    FieldError naming ``field`` otherwise."""
    if not str(path).strip():
        raise FieldError(field, "must name a folder")
    return _checked(Path(path), field, inputs, folder=True)


def check_out_file(path: Path | str, field: str = "out", inputs: Iterable[Path] = ()) -> Path:
    """An output file that is the command's own to write: not an existing folder or special
    file, not a symbolic link out of its folder, its folder writable, not another run's file
    and none of ``inputs``; FieldError naming ``field`` otherwise."""
    if not str(path).strip():
        raise FieldError(field, "must name a file")
    path = Path(path)
    if not path.name:
        raise FieldError(field, f"{str(path)!r}: must name a file")
    return _checked(path, field, inputs, folder=False)


def _checked(path: Path, field: str, inputs: Iterable[Path], folder: bool) -> Path:
    """The checks an output folder and an output file share."""
    check_path_name(path, field)
    try:
        check_out_path(path, folder)
        check_writable(path if folder else path.parent)
        check_not_owned(path)
        check_not_input(path, inputs, "--" + field.removeprefix("--"))
    except ValueError as exc:
        raise FieldError(field, str(exc)) from None
    if not folder:
        _check_replaceable(path, field)
    return path


def add_executor_options(p: argparse.ArgumentParser) -> None:
    """``--executor`` and ``--scheduler``: where the command's tasks run (not its outputs)."""
    p.add_argument(
        "--executor",
        choices=EXECUTORS,
        help="inline (this process), pool (local worker processes; --workers 1 is inline) or "
        "dask (a LocalCluster of --workers processes) (default pool; dask with --scheduler)",
    )
    p.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="a running Dask scheduler (dask scheduler) whose workers run the tasks; implies "
        "--executor dask (docs/dask.md)",
    )


_SCHEDULER = re.compile(r"tcp://(?P<host>[A-Za-z0-9.-]+|\[[0-9A-Fa-f:]+\]):(?P<port>[0-9]{1,5})")


def check_executor(executor: str | None, scheduler: str | None, workers: int | None = None) -> str:
    """The executor the options name; ``--workers`` (when given) must be 1 with ``inline``, which
    runs one task at a time in this process; a ``--scheduler`` must be well formed and usable.

    FieldError naming the option otherwise, before any work: an address that does not answer
    as a Dask scheduler with at least one worker within :data:`CONNECT_TIMEOUT_S` in all (any
    listening port, a scheduler without workers) is reported, not waited on, since the run
    would otherwise hang on it.
    """
    if executor == "inline" and workers is not None and workers > 1:
        raise FieldError(
            "workers",
            f"{workers}: --executor inline runs one task at a time in this process; "
            "use --executor pool or dask for more",
        )
    if scheduler is None:
        return executor or "pool"
    if executor not in (None, "dask"):
        raise FieldError("scheduler", f"needs --executor dask, not --executor {executor}")
    match = _SCHEDULER.fullmatch(scheduler)
    if match is None or not 1 <= int(match["port"]) <= 65535:
        raise FieldError(
            "scheduler", f"{scheduler!r}: must be tcp://HOST:PORT with PORT in 1..65535"
        )
    host = match["host"].strip("[]")
    deadline = time.monotonic() + CONNECT_TIMEOUT_S
    waited = f"waited up to {CONNECT_TIMEOUT_S} s"
    try:  # fast and plain when nothing listens: the Dask client would retry until the deadline
        socket.create_connection((host, int(match["port"])), CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise FieldError(
            "scheduler",
            f"{scheduler}: no scheduler answers ({reason}; {waited}); "
            "start one with `dask scheduler`",
        ) from None
    from bench.common.dask_backend import scheduler_workers  # distributed: slow to import

    try:
        workers = scheduler_workers(scheduler, max(deadline - time.monotonic(), 0.1))
    except Exception as exc:  # any peer that is not a scheduler, however it fails
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:120]
        raise FieldError(
            "scheduler",
            f"{scheduler}: accepts connections but no Dask scheduler answers ({reason}; "
            f"{waited}); start one with `dask scheduler`",
        ) from None
    if workers == 0:
        raise FieldError(
            "scheduler",
            f"{scheduler}: the scheduler has no workers ({waited}); "
            f"start at least one with `dask worker {scheduler}`",
        )
    return "dask"


def check_variant(requested: str | None) -> None:
    """A ``--variant`` this machine cannot run (cuda_ad_rgb without a GPU, llvm_ad_rgb without
    libLLVM) is refused before any command claims a folder; setting it here is what the command
    would do first anyway (idempotent)."""
    if requested is None:
        return
    from renderers.variant import gpu_present, select_variant

    if requested.startswith("cuda") and not gpu_present():
        raise FieldError("variant", f"{requested} needs an NVIDIA GPU; this machine has none")
    try:
        select_variant(requested)
    except (ValueError, RuntimeError) as exc:
        reason = str(exc).removeprefix("no Mitsuba variant could be set: ")
        raise FieldError("variant", f"cannot be used on this machine: {reason}") from None

"""Safe file output: write beside the target and rename on success (never a half file), one
writer per output at a time (`output_lock`, `writes`), and never an output over an input."""

from __future__ import annotations

import contextlib
import functools
import inspect
import os
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

from common.errors import CrankError

F = TypeVar("F", bound=Callable[..., Any])


class OutputError(CrankError, OSError):
    """The output path cannot be written."""


def check_writable(path: str | Path) -> Path:
    """Create `path`'s directory if needed and prove a file can be written there.

    Raises:
      OutputError: naming the path and the reason, before any long work starts.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"output path is a directory, expected a file: {path}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot write to {path.parent}: {exc.strerror or exc}") from None
    _probe(path.parent, prefix=f".{path.name}.")
    return path


def _probe(folder: Path, *, prefix: str) -> None:
    """Write and remove an empty file in `folder`; OutputError naming it if that fails."""
    try:
        fd, probe = tempfile.mkstemp(prefix=prefix, suffix=".probe", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"cannot write to {folder}: {exc.strerror or exc}") from None


def check_creatable(path: str | Path) -> None:
    """Prove that `path` (a folder or file that may not exist yet) could be made, without making
    anything: a probe file in the nearest folder of it that exists. The CLI calls it before it
    imports a long step's modules, so that a read-only or forbidden place is one line in about
    a second, and a refusal after it leaves no empty folder behind.

    Raises:
      OutputError: naming that folder and the reason.
    """
    place = Path(path).absolute()
    while not place.exists() and place != place.parent:
        place = place.parent
    _probe(place, prefix=".crank.")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success rename it to `path`, else delete it. An
    OSError while writing (a full disk) becomes an OutputError naming `path`."""
    path = check_writable(path)
    # The writer's pid in the name: a temporary a killed process left is told from a live one's.
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.{os.getpid()}.", suffix=".partial", dir=path.parent
    )
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions.
    try:
        yield Path(tmp)
        os.replace(tmp, path)
        register_output(path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, CrankError):  # full disk, I/O error
            raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
        raise


def lock_path(path: str | Path) -> Path:
    """The lock file of an output: `.<name>.lock` beside it."""
    path = Path(path)
    return path.parent / f".{path.name}.lock"


def _lock_owner(lock: Path) -> int | None:
    try:
        return int(lock.read_text().strip())
    except (OSError, ValueError):
        return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process
    return True


@contextlib.contextmanager
def output_lock(path: str | Path) -> Iterator[Path]:
    """Hold the output `path` (a file or a run folder) for one whole step, so that a second crank
    process writing the same output at the same time is refused in one line instead of both
    writing it (a lock file created by an atomic hard link, holding the owner's pid). A lock whose
    process is gone (killed) is stale and taken over. Folders made for the lock are removed again
    if the step leaves them empty (a refused input leaves no folder behind). Yields the path.

    Raises:
      OutputError: another live process holds the output, or its directory is not writable.
    """
    path = Path(path)
    lock = lock_path(path)
    made = _missing_ancestors(path.parent)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".lockfile", dir=path.parent)
        with os.fdopen(fd, "w") as f:
            f.write(f"{os.getpid()}\n")
    except OSError as exc:
        raise OutputError(f"cannot write to {path.parent}: {exc.strerror or exc}") from None
    try:
        try:
            _take(lock, tmp, path)
        finally:
            os.unlink(tmp)
    except BaseException:
        _remove_empty(made)
        raise
    remove_stale_partials(path.parent)
    try:
        yield path
    finally:
        if _lock_owner(lock) == os.getpid():
            with contextlib.suppress(FileNotFoundError):
                os.unlink(lock)
        _remove_empty(made)


def remove_stale_partials(folder: Path) -> list[Path]:
    """Delete the hidden temporaries `.<name>.<pid>.<random>.partial` (`atomic_path`) in `folder`
    whose process is gone: what a killed step left. A live writer's are kept. Returns them."""
    removed = []
    for tmp in folder.glob(".*.partial"):
        fields = tmp.name.split(".")
        try:
            pid = int(fields[-3])
        except (ValueError, IndexError):
            continue
        if not _alive(pid):
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
                removed.append(tmp)
    return removed


def _take(lock: Path, tmp: str, path: Path) -> None:
    """Link `tmp` (holding our pid) to `lock`; a lock of a dead process is taken over."""
    for _ in range(3):
        try:
            os.link(tmp, lock)  # atomic: fails if the lock exists
            return
        except FileExistsError:
            owner = _lock_owner(lock)
            if owner is not None and _alive(owner):
                raise OutputError(
                    f"{path} is being written by another crank process (pid {owner}); wait for "
                    f"it to finish or choose another output"
                ) from None
            with contextlib.suppress(FileNotFoundError):
                os.unlink(lock)  # stale: its process was killed
    raise OutputError(f"{path}: could not take its lock {lock}")


def _missing_ancestors(folder: Path) -> list[Path]:
    """`folder` and its ancestors that do not exist yet, deepest first."""
    missing = []
    for candidate in (folder, *folder.parents):
        if candidate.exists():
            break
        missing.append(candidate)
    return missing


def _remove_empty(folders: list[Path]) -> None:
    for folder in folders:  # deepest first
        try:
            folder.rmdir()
        except OSError:  # not empty (the step wrote into it), or already gone
            return


def check_distinct(
    outputs: dict[str, str | Path], inputs: dict[str, str | Path | Sequence[str | Path]]
) -> None:
    """Refuse an output that is one of the inputs (it would be destroyed before it is read), or a
    folder that holds one, resolved through links and relative paths; an input may name several
    files.

    Raises:
      OutputError: naming both.
    """
    named = [
        (name, source)
        for name, given in inputs.items()
        for source in (given if isinstance(given, list | tuple) else [given])
    ]  # an input may be several files (crank import's tables)
    for out_name, out in outputs.items():
        target = Path(out).resolve()
        for in_name, source in named:
            source_path = Path(source).resolve()
            if source_path == target or target in source_path.parents:
                raise OutputError(
                    f"{out_name} {out} would overwrite the {in_name} {source}: choose another "
                    f"output"
                )


def check_suffix(path: str | Path, suffix: str) -> None:
    """Refuse an output path whose suffix is not the format it will hold (OutputError)."""
    if Path(path).suffix != suffix:
        raise OutputError(f"the output is {suffix[1:]}: it must end in {suffix}, got {path}")


def check_output(
    name: str,
    out: str | Path,
    *,
    suffix: str | None,
    inputs: dict[str, str | Path | Sequence[str | Path] | None],
) -> None:
    """What `writes` refuses before its step starts, in its order: an output `name` whose suffix
    is not `suffix` (if given), then one that is one of `inputs` (None: not given). The CLI calls
    it before it imports the step's modules, so that a bad output is one line in about a second
    rather than after torch, CasADi and matplotlib are loaded.

    Raises:
      OutputError: the first of the two faults found.
    """
    if suffix is not None:
        check_suffix(out, suffix)
    check_distinct({name: out}, {n: path for n, path in inputs.items() if path is not None})


_STEPS: list[list[Path]] = []
"""The files each running `writes` step has put in place so far, innermost step last."""


def register_output(path: str | Path) -> None:
    """Record a file just put in place at its final path, so that the running step removes it if
    it fails later (`writes`): a step's outputs appear all together or not at all."""
    if _STEPS:
        _STEPS[-1].append(Path(path))


def writes(
    output: str,
    *,
    inputs: tuple[str, ...] = (),
    suffix: str | None = None,
    all_or_nothing: bool = True,
) -> Callable[[F], F]:
    """Decorator for a step that writes the output named by its argument `output`: the output must
    end in `suffix` (if given, `check_suffix`), is refused if it is one of the arguments `inputs`
    (`check_distinct`), and is held for the whole step (`output_lock`). If the step fails (a full
    disk, a solver error after the first file), every file it had put in place is removed again
    (not with all_or_nothing=False: a run folder keeps its config and finished stages, and says
    it did not finish by lacking its report); a nested step that finished keeps its files."""

    def decorate(function: F) -> F:
        signature = inspect.signature(function)

        @functools.wraps(function)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            out = bound.arguments[output]
            check_output(output, out, suffix=suffix, inputs={n: bound.arguments[n] for n in inputs})
            with output_lock(out):
                _STEPS.append([])
                try:
                    return function(*args, **kwargs)
                except BaseException:
                    for path in _STEPS[-1] if all_or_nothing else ():
                        with contextlib.suppress(OSError):
                            path.unlink()
                    raise
                finally:
                    _STEPS.pop()

        return wrapper  # type: ignore[return-value]

    return decorate

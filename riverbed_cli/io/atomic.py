"""Every output file goes through here: claimed, written under a temporary name beside it, checked, renamed.

The rule, for every writer (TIFF, COG, LAS/LAZ, PLY, PNG, PFM, JSON, YAML, results files):

1. **Claim** (:func:`check_output`, called before any work): the output may be written (it does not exist, or
   ``overwrite``), its folder exists, it is not one of the run's inputs nor another of its outputs, and no other
   riverbed run is writing it. The claim is a lock (``fcntl.flock``) on the output's temporary file, whose name is
   fixed by the output's name (``.STEM.XXXXXXXX.tmp.SUFFIX``, the 8 hex digits a hash of the name): a second run
   writing the same output finds it locked and stops with "in use by another riverbed run". A lock dies with its
   process, so a killed run never blocks the next.
2. **Write** (:func:`atomic_output`): the writer fills the temporary file. Writers that go through Python's file
   objects raise on a full disk or a file-size limit; GDAL does not always (a compressed GeoTIFF's last blocks are
   written when the dataset is closed, and an error there is only printed), so a TIFF written by GDAL is read back
   whole (:func:`verify_raster`) before it counts as written.
3. **Commit**: the temporary file is flushed to disk (``fsync``) and renamed over the output; without ``overwrite``
   the rename refuses to replace a file that appeared meanwhile (a hard link, which fails on an existing name).
   Any failure removes the temporary file, leaves the old output as it was and raises a one-line
   :class:`~riverbed_cli.errors.RiverbedError` naming the output (never the temporary name).

Temporary files a killed run left (riverbed's names, unlocked) are removed when a later run claims an output in the
same folder. Outputs written together (``riverbed dsm``'s DSM and points) nest their :func:`atomic_output` blocks:
the renames happen one after the other when the outermost block ends, after every file has been written.
"""

import contextlib
import errno
import fcntl
import functools
import hashlib
import logging
import os
import re
import shutil
import tempfile
import threading
import warnings
from pathlib import Path

import rasterio

from ..errors import RiverbedError

log = logging.getLogger(__name__)

#: riverbed's temporary names: ``.STEM.XXXXXXXX.tmp.SUFFIX`` (8 hex digits; the stem cut so the name fits)
TEMP_NAME = re.compile(r"^\..+\.[0-9a-f]{8}\.tmp(\.[^.]*)?$")
_NAME_MAX = 255  # bytes in a file name on every common file system
_SUFFIX_MAX = 16
#: file suffixes GDAL writes (read back whole before they count as written)
RASTER_SUFFIXES = (".tif", ".tiff")
#: GDAL's block cache while a written raster is read back: each block is read once, so a small one costs no speed
VERIFY_CACHE_BYTES = 16 * 2**20


class _Claim:
    """An output this process will write: its temporary path and the open, locked file descriptor of it."""

    def __init__(self, path, tmp, fd):
        self.path, self.tmp, self.fd = path, tmp, fd
        self.depth = 0  # open atomic_output blocks on it


_claims = {}  # absolute output path -> _Claim
_lock = threading.Lock()


def temporary_name(path):
    """The temporary file an output is written to: ``.STEM.XXXXXXXX.tmp.SUFFIX`` beside it (8 hex digits of a hash
    of the name; the stem shortened so the whole name stays within 255 bytes, as long as the output's own)."""
    path = Path(path)
    suffix = path.suffix if len(path.suffix.encode()) <= _SUFFIX_MAX else ""
    digest = hashlib.sha1(path.name.encode("utf-8", "surrogateescape")).hexdigest()[:8]
    tail = f".{digest}.tmp{suffix}"
    stem = path.stem.encode("utf-8", "surrogateescape")[: _NAME_MAX - 1 - len(tail.encode())]
    stem = stem.decode("utf-8", "ignore") or "out"
    return path.with_name(f".{stem}{tail}")


def _key(path):
    return os.path.abspath(path)


def _folder(path):
    path = Path(path)
    return path.parent if str(path.parent) else Path(".")


def check_output(path, overwrite=False, inputs=()):
    """Claim ``path`` for this run (module docstring): refuse it if it exists and ``overwrite`` is false, if its
    folder is missing, if it is one of ``inputs`` (paths this run reads), or if another riverbed run is writing it.

    Claiming an output twice in one process is allowed (the library calls this again when it writes). Raises
    :class:`RiverbedError` naming ``path``.
    """
    path = Path(path)
    for source in inputs:
        if isinstance(source, (str, os.PathLike)) and same_file(path, source):
            raise RiverbedError(f"is also an input of this run ({source}); riverbed never writes over its input",
                                path)
    if path.is_dir():
        raise RiverbedError("is a folder, not a file", path)
    if path.exists() and not overwrite:
        raise RiverbedError("output exists; pass --overwrite to replace it", path)
    parent = _folder(path)
    if not parent.is_dir():
        raise RiverbedError(f"output folder {parent} does not exist", path)
    _claim(path)


def check_outputs(outputs, overwrite=False, inputs=()):
    """:func:`check_output` for each of ``outputs`` (``None`` entries skipped), refusing the same file given twice
    as an output (e.g. ``--color`` equal to ``-o``)."""
    given = [Path(p) for p in outputs if p is not None]
    for i, path in enumerate(given):
        for other in given[:i]:
            if same_file(path, other):
                raise RiverbedError("given twice as an output of this run", path)
    for path in given:
        check_output(path, overwrite, inputs)


def check_output_folder(outdir, names=(), overwrite=False, inputs=()):
    """Raise unless ``outdir`` is an existing folder or a new name inside an existing one, and (when it exists)
    claim each of the output ``names`` inside it (:func:`check_output`, none of them one of ``inputs``); returns its
    parent."""
    outdir = Path(outdir)
    parent = _folder(outdir)
    if not parent.is_dir():
        raise RiverbedError(f"folder {parent} does not exist", outdir)
    if outdir.exists() and not outdir.is_dir():
        raise RiverbedError("exists and is not a folder", outdir)
    if outdir.is_dir():
        for name in names:
            check_output(outdir / name, overwrite, inputs)
    return parent


def same_file(a, b):
    """True when the paths ``a`` and ``b`` name one file (the same absolute path, or one file through links)."""
    a, b = Path(a), Path(b)
    if os.path.abspath(a) == os.path.abspath(b) or a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _claim(path):
    key = _key(path)
    with _lock:
        if key in _claims:
            return _claims[key]
        tmp = temporary_name(path)
        try:
            remove_stale_temporaries(_folder(path))
            fd = _locked(tmp, path, "in use by another riverbed run (it is being written); wait for that run or "
                         "choose another output")
            os.ftruncate(fd, 0)  # a killed run's leftover under the same name
        except OSError as e:
            raise RiverbedError(f"cannot write ({e.strerror or e})", path) from None
        claim = _Claim(Path(path), tmp, fd)
        _claims[key] = claim
        return claim


def _locked(lock, named, busy):
    """An open descriptor of the file ``lock`` (created) holding its exclusive ``flock``; a :class:`RiverbedError`
    ``busy`` naming ``named`` when another process holds it."""
    for _ in range(3):
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise RiverbedError(busy, named) from None
        try:  # another run may have removed the name between our open and lock (a cleaner, an ending run): anew
            if os.stat(lock).st_ino == os.fstat(fd).st_ino:
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)
    raise RiverbedError("cannot lock it (its lock file keeps being replaced)", named)


def release_claims(paths=None):
    """Give up the claims of ``paths`` (default: every claim of this process) that no :func:`atomic_output` block
    holds: their unfinished temporary files are removed and their locks released. The CLI calls this when a command
    ends; :func:`releases_claims` for library functions."""
    with _lock:
        keys = list(_claims) if paths is None else [_key(p) for p in paths]
        for key in keys:
            claim = _claims.get(key)
            if claim is None or claim.depth:
                continue
            del _claims[key]
            _drop(claim)


def _drop(claim):
    with contextlib.suppress(OSError):
        if os.stat(claim.tmp).st_ino == os.fstat(claim.fd).st_ino:  # not renamed into place: unfinished
            os.unlink(claim.tmp)
    with contextlib.suppress(OSError):
        os.close(claim.fd)


def releases_claims(func):
    """Decorate a library function that claims outputs (:func:`check_output`): the claims it made and did not
    write are released when it returns or raises, so a long-lived process (a dask worker) holds no lock after a
    failed call."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        before = set(_claims)
        try:
            return func(*args, **kwargs)
        finally:
            release_claims([k for k in list(_claims) if k not in before])

    return wrapper


def remove_stale_temporaries(folder):
    """Remove riverbed's temporary files in ``folder`` that no running riverbed holds (a killed run's); returns
    their names."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        if not (entry.name.startswith(".") and TEMP_NAME.match(entry.name)) or _key(entry.path) in _held_temps():
            continue
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
            fd = os.open(entry.path, os.O_RDONLY | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # a running writer holds it: not stale
            os.unlink(entry.path)
            removed.append(entry.name)
        except OSError:
            pass
        finally:
            os.close(fd)
    if removed:
        log.info("%s: removed %d temporary file(s) a stopped run left", folder, len(removed))
        _removed.extend(os.path.join(folder, name) for name in removed)
    return removed


_removed = []  # paths remove_stale_temporaries removed in this process, until taken by taken_temporaries


def taken_temporaries():
    """The paths of the killed runs' temporary files this process has removed since the last call (a block reports
    them with its own clean-up)."""
    out = list(_removed)
    _removed.clear()
    return out


def _held_temps():
    return {_key(c.tmp) for c in _claims.values()}


@contextlib.contextmanager
def atomic_output(path, overwrite=False, verify=None):
    """Yield the temporary path of ``path`` (same suffix); on success check it, flush it and rename it to ``path``.

    Claims ``path`` (:func:`check_output`) unless this process has. On any exception the temporary file is
    removed, ``path`` is left as it was, and an ``OSError`` (a full disk, a file-size limit) or a
    :class:`RiverbedError` naming the temporary file is raised as a one-line :class:`RiverbedError` naming
    ``path``. Inside an :func:`output_group` (or another ``atomic_output`` block) the rename waits for its end.
    ``verify``: read the file back (:func:`verify_raster`) before it counts as written; default: for TIFFs, which
    GDAL may have written (a writer that wrote the bytes itself, through Python, passes False).
    """
    path = Path(path)
    if _key(path) in _held_temps():  # a writer handed an open block's temporary file: it is written there
        yield path
        return
    if _key(path) not in _claims:
        check_output(path, overwrite)
    claim = _claims[_key(path)]
    claim.depth += 1
    try:
        with output_group():
            _nesting.opened.append(claim)
            try:
                yield claim.tmp
                _finish(claim, claim.tmp.suffix.lower() in RASTER_SUFFIXES if verify is None else verify)
            except RiverbedError as e:
                if e.path is not None and e.path == str(claim.tmp):
                    raise RiverbedError(str(e)[len(e.path) + 2:], path) from None
                raise
            except OSError as e:
                raise RiverbedError(f"cannot write ({_reason(e)})", path) from None
            _nesting.written.append((claim, overwrite))
    finally:
        claim.depth -= 1
        if _nesting.depth == 0:
            release_claims([path])  # renamed, or failed: its temporary file removed


@contextlib.contextmanager
def output_group():
    """Outputs written together: every :func:`atomic_output` block inside writes and checks its file, and all are
    renamed into place, one after the other, when the group ends without an error; on an error none is."""
    _nesting.depth += 1
    try:
        yield
        if _nesting.depth == 1:
            for claim, overwrite in _nesting.written:
                _rename(claim, overwrite)
    finally:
        _nesting.depth -= 1
        if _nesting.depth == 0:
            opened, _nesting.opened, _nesting.written = _nesting.opened, [], []
            release_claims([c.path for c in opened])  # the unfinished ones' temporary files removed


class _Nesting(threading.local):
    """The open :func:`output_group` blocks of this thread, and the outputs written inside the outermost one."""

    def __init__(self):
        self.depth = 0
        self.opened = []  # claims of the atomic_output blocks opened in the outermost group
        self.written = []  # (claim, overwrite) of those written, renamed when the outermost group ends


_nesting = _Nesting()


def _finish(claim, verify):
    """Check what was written and flush it to disk, before it may be renamed into place."""
    tmp = claim.tmp
    if not tmp.exists():
        raise RiverbedError("nothing was written", claim.path)
    if verify:
        verify_raster(tmp, claim.path)
    fd = os.open(tmp, os.O_RDONLY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _rename(claim, overwrite):
    tmp, path = claim.tmp, claim.path
    try:
        if overwrite:
            os.replace(tmp, path)
        else:
            try:
                os.link(tmp, path)  # fails if the name exists: never replaces a file that appeared meanwhile
            except FileExistsError:
                raise RiverbedError("output exists (written meanwhile by something else); pass --overwrite to "
                                    "replace it", path) from None
            except OSError as e:
                if e.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.EXDEV):
                    raise
                if path.exists():  # no hard links on this file system: check, then rename
                    raise RiverbedError("output exists (written meanwhile by something else); pass --overwrite "
                                        "to replace it", path) from None
                os.replace(tmp, path)
            else:
                os.unlink(tmp)
        _fsync_folder(_folder(path))
    except OSError as e:
        raise RiverbedError(f"cannot write ({_reason(e)})", path) from None


def _fsync_folder(folder):
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY | os.O_CLOEXEC)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _reason(e):
    if e.errno == errno.ENOSPC:
        return "no space left on the device"
    if e.errno == errno.EFBIG:
        return "file too large for the file-size limit or the file system"
    return e.strerror or str(e)


#: the lock file of a folder a run writes as a whole (``riverbed block``'s output folder)
FOLDER_LOCK = ".riverbed.lock"
_folder_locks = {}  # absolute folder -> file descriptor of its locked lock file (this process)


def lock_folder(folder):
    """Lock the output ``folder`` for this process (a ``fcntl.flock`` on ``folder/.riverbed.lock``) until
    :func:`unlock_folder` or the process ends; a :class:`RiverbedError` naming it when another run holds it.
    Locking a folder this process holds again does nothing."""
    key = _key(folder)
    with _lock:
        if key in _folder_locks:
            return
        try:
            fd = _locked(Path(folder) / FOLDER_LOCK, folder, "in use by another riverbed run (it is writing into "
                         "this folder); wait for that run or choose another output folder")
        except OSError as e:
            raise RiverbedError(f"cannot lock the output folder ({e.strerror or e})", folder) from None
        _folder_locks[key] = fd


def unlock_folder(folder):
    """Release :func:`lock_folder`'s lock on ``folder`` and remove its lock file (a killed run's stays, unlocked,
    until the next run takes it)."""
    with _lock:
        fd = _folder_locks.pop(_key(folder), None)
    if fd is not None:
        with contextlib.suppress(OSError):
            os.unlink(Path(folder) / FOLDER_LOCK)  # while locked: a run that opened it meanwhile retries
        os.close(fd)


@contextlib.contextmanager
def staging_folder(outdir):
    """A new hidden folder beside ``outdir`` (``.NAME.XXXXXXXX.tmp``) to write a set of outputs into before they are
    moved into ``outdir`` together; removed at the end, whatever happens. A :class:`RiverbedError` naming a file in
    it is raised naming that file in ``outdir`` instead. Staging folders a killed run left beside ``outdir`` are
    removed first (each is locked, :func:`lock_folder`, while its run lives)."""
    outdir = Path(outdir)
    parent = _folder(outdir)
    pattern = re.compile(rf"^\.{re.escape(outdir.name)}\.[a-z0-9_]{{8}}\.tmp$")
    with contextlib.suppress(OSError):
        for entry in os.scandir(parent):
            if pattern.match(entry.name) and entry.is_dir(follow_symlinks=False) and _unlocked(entry.path):
                shutil.rmtree(entry.path, ignore_errors=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{outdir.name}.", suffix=".tmp", dir=parent))
    try:
        lock_folder(tmp)
        try:
            yield tmp
        except RiverbedError as e:
            if e.path is not None and Path(e.path).is_relative_to(tmp):
                raise RiverbedError(str(e)[len(e.path) + 2:], outdir / Path(e.path).relative_to(tmp)) from None
            raise
    finally:
        unlock_folder(tmp)
        shutil.rmtree(tmp, ignore_errors=True)


def _unlocked(folder):
    """True when no process holds ``folder``'s :func:`lock_folder` lock (or it has none)."""
    try:
        fd = os.open(Path(folder) / FOLDER_LOCK, os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return True
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


_quiet = {"depth": 0, "saved": None}
_quiet_lock = threading.Lock()


@contextlib.contextmanager
def c_stderr_silenced():
    """Discard what C libraries print on the process's stderr (file descriptor 2) inside the block.

    libtiff prints its write errors there itself ("_tiffWriteProc: File too large."), bypassing GDAL's and Python's
    error handling; the write is checked afterwards (:func:`verify_raster`) and reported in one line instead.
    Python's own ``sys.stderr`` is the same descriptor: keep the block to the library calls. Nested and concurrent
    blocks share one redirection (restored when the last one ends).
    """
    with _quiet_lock:
        if _quiet["depth"] == 0:
            try:
                saved = os.dup(2)
                null = os.open(os.devnull, os.O_WRONLY | os.O_CLOEXEC)
            except OSError:
                saved = None
            else:
                os.dup2(null, 2)
                os.close(null)
            _quiet["saved"] = saved
        _quiet["depth"] += 1
    try:
        yield
    finally:
        with _quiet_lock:
            _quiet["depth"] -= 1
            if _quiet["depth"] == 0 and _quiet["saved"] is not None:
                os.dup2(_quiet["saved"], 2)
                os.close(_quiet["saved"])
                _quiet["saved"] = None


def verify_raster(tmp, path=None):
    """Read every block of the raster file ``tmp`` back; a :class:`RiverbedError` naming ``path`` when it cannot be
    read whole (GDAL reports a full disk or a file-size limit while closing a compressed file only on stderr)."""
    try:
        with rasterio.Env(GDAL_CACHEMAX=VERIFY_CACHE_BYTES), warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(tmp) as ds:
                for band in range(1, ds.count + 1):
                    for _, window in ds.block_windows(band):
                        ds.read(band, window=window)
    except (rasterio.errors.RasterioError, OSError, ValueError):
        raise RiverbedError("cannot write: the file written is incomplete (is the disk full, or a file-size limit "
                            "set?)", path or tmp) from None

"""Planning a block: the output folder, the raw pairs rectified, and per pair run, skip (a verified ``done.json``) or
failed; the block's file names and the JSON records and hashes of its outputs."""

import contextlib
import hashlib
import json
import logging
import os
import re
import shutil
import time
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path


from ...errors import RiverbedError
from ...geometry.rectify import rectify_files
from ...geometry.rpc_pair import rectify_rpc_files
from ...io.atomic import FOLDER_LOCK, TEMP_NAME, atomic_output, lock_folder, taken_temporaries
from ...io.images import header_size, read_image
from ...geometry.pairfile import load_pairfile
from .manifest import RAW_KEYS, RPC_KEYS, Manifest, load_manifest

log = logging.getLogger(__name__)

OUTPUTS = ("sparse.tif", "disparity.tif", "points.laz", "dsm.tif")
#: the output of a pair with LiDAR only (a pair without a cloud is matched from its images alone)
LIDAR_OUTPUT = "sparse.tif"
DONE = "done.json"
MARKER = "block.json"
WORK = ".work"
MERGED = "dsm.tif"
#: Where an ``rpc:`` or ``raw:`` entry's rectified pair goes, under ``pairs/NAME/``.
RECTIFIED = "rectified"


def clean_temps(folder, names=None):
    """Remove the temporary files a killed writer left in ``folder`` (``.STEM.XXXXXXXX.tmp.SUFFIX``, see
    :func:`~riverbed_cli.io.atomic.atomic_output`): those of the output ``names``, or every one (``None``).

    Returns the paths removed, sorted.
    """
    folder = Path(folder)
    if names is None:
        pattern = TEMP_NAME
    else:
        alts = [rf"\.{re.escape(Path(n).stem)}\.[0-9a-f]{{8}}\.tmp{re.escape(Path(n).suffix)}" for n in names]
        pattern = re.compile("^(" + "|".join(alts) + ")$")
    try:
        found = sorted(p for p in folder.iterdir() if pattern.match(p.name))
    except OSError:  # no such folder
        return []
    removed = []
    for p in found:
        with contextlib.suppress(OSError):
            if p.is_file() and not p.is_symlink():
                p.unlink()
                removed.append(p)
    return removed


def clean_pair_leftovers(folder, finished):
    """What an interrupted run leaves in a pair's folder: temporary files (in it, ``.work/`` and ``rectified/``)
    and, for a ``finished`` pair (killed between its ``done.json`` and removing them), the image copies in
    ``.work/``. Returns the paths removed."""
    folder = Path(folder)
    removed = [p for sub in (folder, folder / WORK, folder / RECTIFIED) for p in clean_temps(sub)]
    work = folder / WORK
    if finished and work.is_dir() and not work.is_symlink():
        removed += sorted(p for p in work.iterdir())
        shutil.rmtree(work, ignore_errors=True)
    return removed


def rectify_raw(spec, outdir):
    """Rectify a raw entry into ``outdir/pairs/NAME/rectified/`` (unless done for the same inputs); its pair file."""
    folder = Path(outdir) / "pairs" / spec.name / RECTIFIED
    stamp = folder / "inputs.json"
    r = spec.raw
    # the stamp holds the inputs and the settings: changing alpha or size re-rectifies
    inputs = [_stat(r[k], r[k].parent) for k in RAW_KEYS] + [
        {"alpha": r["alpha"], "size": list(r["size"]) if r["size"] else None}]
    if (folder / "pair.yaml").is_file() and stamp.is_file() and json.loads(stamp.read_text()) == inputs:
        return folder / "pair.yaml"
    folder.parent.mkdir(parents=True, exist_ok=True)
    rectify_files(r["left"], r["left_orientation"], r["right"], r["right_orientation"], folder, overwrite=True,
                  alpha=r["alpha"], size=r["size"])
    write_json(stamp, inputs)
    return folder / "pair.yaml"


def rpc_stamp(rpc, clouds, settings):
    """What an ``rpc:`` entry's rectification depends on: its files (name, size, mtime), ROI, heights, datum,
    pointing and, when the heights come from the LiDAR, the clouds and the settings that select their points."""
    files = [_stat(rpc[k], Path(rpc[k]).parent) for k in RPC_KEYS]
    if rpc["dem"] is not None:
        files.append(_stat(rpc["dem"], Path(rpc["dem"]).parent))
    options = {k: rpc[k] for k in ("roi", "heights", "vertical", "pointing")}
    if rpc["dem"] is None and rpc["heights"] is None:
        files += [_stat(c, Path(c).parent) for c in clouds]
        options.update({k: settings[k] for k in ("lidar_crs", "classes", "drop_classes")})
    return files + [options]


def rectify_rpc(job):
    """Rectify an ``rpc:`` job's ROI into ``pairs/NAME/rectified/`` (``riverbed rectify --rpc``), unless done for
    the same inputs (``rectified/inputs.json``); its pair file. The height range: ``dem``, ``heights``, the
    pair's clouds (:func:`~riverbed_cli.geometry.rpc_pair.heights_from_lidar`) or, without clouds, the images' tie
    points (:func:`~riverbed_cli.geometry.rpc_heights.heights_from_tie_points`)."""
    r, s = job.rpc, job.settings
    folder = Path(job.folder) / RECTIFIED
    stamp = folder / "inputs.json"
    inputs = json.loads(json.dumps(rpc_stamp(r, job.clouds, s)))
    if (folder / "pair.yaml").is_file() and stamp.is_file() and json.loads(stamp.read_text()) == inputs:
        return folder / "pair.yaml"
    folder.parent.mkdir(parents=True, exist_ok=True)
    lidar = job.clouds or None if r["dem"] is None and r["heights"] is None else None  # no cloud: tie points
    rectify_rpc_files(r["left"], r["left_rpc"], r["right"], r["right_rpc"], folder, roi=r["roi"], dem=r["dem"],
                      heights=r["heights"], vertical=r["vertical"], pointing=r["pointing"], overwrite=True,
                      max_pixels=s["max_pixels"], lidar=lidar, lidar_crs=s["lidar_crs"], classes=s["classes"],
                      drop_classes=s["drop_classes"], pointing_hint="pointing: false in its rpc: entry")
    write_json(stamp, inputs)
    return folder / "pair.yaml"


@dataclass
class PairJob:
    """Everything a worker needs to run one pair (picklable; absolute paths as strings)."""

    name: str
    index: int
    pair: str
    clouds: list
    settings: dict
    folder: str
    shape: tuple = None  # (H, W)
    settings_hash: str = ""
    inputs: list = field(default_factory=list)
    status: str = "run"  # run | skip | failed (at planning)
    error: str = None
    record: dict = None  # done.json of a skipped pair
    rpc: dict = None  # an rpc: entry (images, RPCs, ROI, heights), rectified by the project stage
    range_map: str = None  # per-pixel disparity ranges of the pair (a 2-band TIFF), searched instead of its tubes


@dataclass
class BlockPlan:
    manifest: Manifest
    outdir: Path
    jobs: list
    seconds: float = 0.0  # validating, stat-ing inputs, verifying finished pairs (sha256 of their outputs)
    cleaned: list = field(default_factory=list)  # leftovers of an interrupted run removed (paths)

    @property
    def to_run(self):
        return [j for j in self.jobs if j.status == "run"]


def riverbed_version():
    """The installed riverbed's version (part of every pair's settings hash), or ``"unknown"``."""
    try:
        return metadata.version("riverbed")
    except Exception:  # noqa: BLE001 - not installed (a source checkout): the hash just leaves it out
        return "unknown"


def _image_shape(path):
    """``(H, W)`` from an image header, or by decoding it (one-line errors) when GDAL cannot read it."""
    size = header_size(path)
    return (size[1], size[0]) if size is not None else read_image(path).shape[:2]


def _stat(path, base):
    """Path (relative to the manifest's folder when inside it, so a block folder can move), size and mtime."""
    path = Path(os.path.normpath(Path(path).absolute()))
    st = path.stat()
    shown = path.relative_to(base) if path.is_relative_to(base) else path
    return {"path": shown.as_posix(), "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _hash_json(obj):
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def sha256_file(path, chunk=1 << 20):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(chunk), b""):
            h.update(block)
    return h.hexdigest()


def verify_done(folder, settings_hash):
    """The pair's ``done.json`` if it verifies (outputs present, sizes and sha256 as recorded, same settings hash),
    else None."""
    folder = Path(folder)
    try:
        record = json.loads((folder / DONE).read_text(encoding="utf-8"))
        if record.get("settings_hash") != settings_hash:
            return None
        outputs = record["outputs"]
        names = [n for n in OUTPUTS if n != LIDAR_OUTPUT or n in outputs]
        for name in names:
            p = folder / name
            if not p.is_file() or p.stat().st_size != outputs[name]["size"]:
                return None
        for name in names:
            if sha256_file(folder / name) != outputs[name]["sha256"]:
                return None
        return record
    except (OSError, ValueError, KeyError, TypeError):
        return None


def prepare_outdir(outdir, manifest_path, overwrite=False):
    """Check (and create) the output folder by the rule in the package notes; write its ``block.json`` marker."""
    out = Path(outdir)
    marker = out / MARKER
    record = {}
    if out.exists():
        if not out.is_dir():
            raise RiverbedError("output exists and is not a folder", out)
        # one block run per folder: a second would remove the first's work files (released by run_block, or when
        # the process ends)
        lock_folder(out)
        if marker.is_file():
            try:
                record = json.loads(marker.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                record = {}
            owner = record.get("manifest") if isinstance(record, dict) else None
            if owner != str(manifest_path) and not overwrite:
                raise RiverbedError(f"holds the block of another manifest ({owner}); pass --overwrite to reuse "
                                    "it", out)
        elif any(p.name != FOLDER_LOCK for p in out.iterdir()) and not overwrite:
            raise RiverbedError("output folder is not empty and holds no block; pass --overwrite to write into "
                                "it", out)
    else:
        parent = out.parent if str(out.parent) else Path(".")
        if not parent.is_dir():
            raise RiverbedError(f"output folder {parent} does not exist", out)
        out.mkdir()
        lock_folder(out)
    if not isinstance(record, dict) or record.get("manifest") != str(manifest_path):
        record = {}
    record.update({"riverbed": "block", "manifest": str(manifest_path)})
    write_json(marker, record)
    return record


def write_json(path, obj):
    with atomic_output(path, overwrite=True) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, default=_plain) + "\n", encoding="utf-8")


def _plain(o):
    if hasattr(o, "item") and getattr(o, "ndim", 1) == 0:
        return o.item()
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)


def plan_block(manifest, outdir, overwrite=False):
    """Validate the manifest, prepare ``outdir`` and decide per pair: run, skip (verified ``done.json``) or failed
    (its pair file or images cannot be read)."""
    t0 = time.perf_counter()
    if not isinstance(manifest, Manifest):
        manifest = load_manifest(manifest)
    outdir = Path(outdir).absolute()
    taken_temporaries()  # from now on, the killed runs' temporaries removed are this block's to report
    prepare_outdir(outdir, manifest.path, overwrite)
    cleaned = clean_temps(outdir, (MERGED, MARKER))
    base = manifest.path.parent
    version = riverbed_version()
    jobs = []
    for spec in manifest.pairs:
        s = spec.settings
        job = PairJob(spec.name, spec.index, str(spec.pair), [str(c) for c in spec.clouds], s,
                      str(outdir / "pairs" / spec.name))
        jobs.append(job)
        cleaned += clean_pair_leftovers(job.folder, finished=False)
        rpc_options = None
        try:
            if spec.rpc is not None:
                # satellite images: each ROI is rectified by its project task (on the workers: it reads image
                # windows and matches tie points); inputs and settings are hashed without the rectified pair
                job.rpc = {k: (str(v) if isinstance(v, Path) else v) for k, v in spec.rpc.items()}
                job.pair = str(Path(job.folder) / RECTIFIED / "pair.yaml")
                files = [spec.rpc[k] for k in RPC_KEYS] + ([spec.rpc["dem"]] if spec.rpc["dem"] else [])
                files += spec.clouds
                rpc_options = {k: spec.rpc[k] for k in ("roi", "heights", "vertical", "pointing")}
            else:
                if spec.raw is not None:
                    # raw frames: rectify first (cheap, here in the planner), then the pair runs like any other
                    spec.pair = rectify_raw(spec, outdir)
                    job.pair = str(spec.pair)
                pair = load_pairfile(spec.pair, accept_rpc=True)
                for side in ("left", "right"):
                    if getattr(pair, side) is None:
                        raise RiverbedError(f"{side}: missing (a block needs the rectified images)", spec.pair)
                shape = pair.image_size or _image_shape(pair.left)
                job.shape = tuple(int(v) for v in shape)
                raw_files = [spec.raw[k] for k in RAW_KEYS] if spec.raw else []
                files = [spec.pair, pair.left, pair.right, *spec.clouds, *raw_files]
                if spec.range_map is not None:
                    job.range_map = str(spec.range_map)
                    files.append(spec.range_map)
            for key in ("registration", "range_dsm"):
                if s[key]:
                    files.append(Path(s[key]))
            job.inputs = [_stat(p, base) for p in files]
        except RiverbedError as e:
            job.status, job.error = "failed", str(e)
            continue
        except OSError as e:
            job.status, job.error = "failed", f"{e.filename or ''}: {e.strerror or e}"
            continue
        hashed = {"name": spec.name, "settings": s, "inputs": job.inputs, "riverbed": version}
        if rpc_options is not None:
            hashed["rpc"] = rpc_options
        job.settings_hash = _hash_json(hashed)
        record = verify_done(job.folder, job.settings_hash)
        if record is not None:
            job.status, job.record = "skip", record
            cleaned += clean_pair_leftovers(job.folder, finished=True)
    cleaned += [p for p in map(Path, taken_temporaries()) if p.is_relative_to(outdir)]  # removed when claiming
    if cleaned:
        log.info("removed %d leftovers of an interrupted run (temporary files, finished pairs' .work)", len(cleaned))
    return BlockPlan(manifest, outdir, jobs, time.perf_counter() - t0, cleaned)


def job_dict(job):
    """A plain dict of a job (for logs and debugging)."""
    return asdict(job)

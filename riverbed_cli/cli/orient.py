"""``riverbed orient``: riverbed orientation files (one YAML per image, the input of ``riverbed rectify``) from an
aero-triangulation export: Orthority, OpenSfM / ODM or COLMAP."""

import logging

import click

from ..geometry.orientation_import import FORMATS, orient_files
from .options import json_opt, overwrite_opt, print_json

log = logging.getLogger(__name__)


def _names(ctx, param, value):
    # --images a.tif,b.tif and --images a.tif --images b.tif alike
    return [name.strip() for given in value for name in given.split(",") if name.strip()] or None


@click.command("orient")
# folders too: a COLMAP model folder or an ODM project; the readers report missing files in one line
@click.argument("inputs", nargs=-1, required=True, type=click.Path())
@click.option("-o", "--outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder (created if missing): one STEM.yaml per image.")
@click.option("--format", "fmt", type=click.Choice(("auto",) + FORMATS), default="auto", show_default=True,
              help="Export format; auto tells it from the file names.")
@click.option("--images", multiple=True, callback=_names, metavar="NAME[,NAME...]",
              help="Only these images (file names, with or without extension; repeatable). Default: all.")
@click.option("--crs", default=None, metavar="CRS",
              help="Projected CRS of the output centres (e.g. EPSG:32651): x, y, z are taken to be in it (it "
                   "replaces a .prj or world_crs); latitude/longitude and OpenSfM's topocentric frame are "
                   "projected into it (default: their UTM zone). COLMAP: written only when given.")
@click.option("--radians", is_flag=True, default=False, help="Orthority CSV angles are in radians (default degrees).")
@overwrite_opt
@json_opt
def orient_cmd(inputs, outdir, fmt, images, crs, radians, overwrite, as_json):
    """Write riverbed orientation files (OUTDIR/STEM.yaml, see docs/rectify.md) from an export's INPUTS.

    \b
    Orthority:  INTERIOR.yaml EXTERIOR.csv|.geojson   (CSV: a .prj beside it gives the CRS)
    OpenSfM:    reconstruction.json (or the ODM project / opensfm folder)
    COLMAP:     cameras.txt images.txt (or their folder; text model)

    All files are written under temporary names and renamed together once all are written; nothing is replaced
    without --overwrite.
    """
    summary = orient_files(inputs, outdir, fmt=fmt, crs=crs, radians=radians, images=images, overwrite=overwrite)
    if as_json:
        print_json(summary)
    else:
        log.info("%s: %d orientation files from %s (crs %s)", outdir, len(summary["frames"]), summary["format"],
                 summary["crs"])

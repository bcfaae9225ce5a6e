"""Pictures: colourised disparity and error maps (RGB ``uint8``), and the pictures riverbed writes with a legend.

Every picture riverbed writes is a :class:`Picture`: the colour-mapped map at 1:1 pixel scale (its pixels exactly
those of :func:`colorize_disparity`, :func:`error_map`, the DSM difference map or the hillshade), a title naming what
it shows with the metric's value, and a legend panel beside it (a colour bar with units, swatches for the no-data
colours; a scale bar for the hillshade) drawn with matplotlib.

Conventions: arrays ``H x W`` indexed ``[row, col]``, disparity ``d = x_left - x_right`` in pixels, NaN
invalid; colour images are ``H x W x 3`` in RGB order.
"""

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..errors import RiverbedError
from ..io.atomic import atomic_output
from ..io.images import write_png_file
from .dsm_compare import compare_dsm, difference_limit, difference_map
from .evaluate import evaluate_disparity

#: Colour bins of the absolute error, in pixels: ``(upper bound, RGB)``; the colours are the KITTI devkit's
#: (blue for small errors ... red for large), the bounds double from 1/16 px to 16 px.
ERROR_BINS = (
    (0.0625, (49, 54, 149)),
    (0.125, (69, 117, 180)),
    (0.25, (116, 173, 209)),
    (0.5, (171, 217, 233)),
    (1.0, (224, 243, 248)),
    (2.0, (254, 224, 144)),
    (4.0, (253, 174, 97)),
    (8.0, (244, 109, 67)),
    (16.0, (215, 48, 39)),
    (np.inf, (165, 0, 38)),
)
#: Colour of ground-truth pixels without a (valid) prediction.
MISSING_COLOUR = (255, 0, 255)


def colorize_disparity(disp, vmin=None, vmax=None):
    """Colourise a disparity map with the Turbo colour map.

    Parameters
    ----------
    disp : array_like, ``H x W``
        Disparity in pixels; NaN (any non-finite value) is invalid.
    vmin, vmax : float, optional
        Disparities mapped to the two ends of the colour map; values outside are clipped. Default: the minimum
        and maximum of the finite values. Min/max rather than percentiles because a matcher's disparities are
        already bounded by its search range; pass the ground truth's range to compare maps on one scale.

    Returns
    -------
    rgb : ndarray of uint8, ``H x W x 3``
        Turbo colours (dark blue = ``vmin`` = far, dark red = ``vmax`` = near); invalid pixels black (Turbo
        itself never reaches pure black).
    """
    disp = np.asarray(disp, dtype=np.float64)
    if disp.ndim != 2:
        raise RiverbedError(f"disparity must be a 2-D array (H x W), got shape {disp.shape}")
    valid = np.isfinite(disp)
    rgb = np.zeros(disp.shape + (3,), np.uint8)
    if not valid.any():
        return rgb
    lo = float(disp[valid].min()) if vmin is None else float(vmin)
    hi = float(disp[valid].max()) if vmax is None else float(vmax)
    span = hi - lo if hi > lo else 1.0  # a constant map gets the lowest colour
    index = np.zeros(disp.shape, np.uint8)
    index[valid] = np.round(np.clip((disp[valid] - lo) / span, 0.0, 1.0) * 255).astype(np.uint8)
    colours = cv2.cvtColor(cv2.applyColorMap(index, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgb[valid] = colours[valid]
    return rgb


def error_map(disp, gt, mask=None):
    """Colour the absolute disparity error per pixel, KITTI style.

    Parameters
    ----------
    disp : array_like, ``H x W``
        Predicted disparity in pixels, NaN invalid.
    gt : array_like, ``H x W``
        Ground-truth disparity in pixels, NaN where unknown.
    mask : array_like of bool, ``H x W``, optional
        Pixels to show (e.g. :func:`riverbed_cli.products.evaluate.evaluation_mask`, which leaves out the
        LiDAR pixels used as guidance); others are drawn black like pixels without ground truth.

    Returns
    -------
    rgb : ndarray of uint8, ``H x W x 3``
        ``|disp - gt|`` in the bins of :data:`ERROR_BINS` (dark blue <= 1/16 px, light blue <= 1 px, yellow
        to red above 1 px, dark red > 16 px; a bin holds errors up to and including its bound). Ground-truth
        pixels with no valid prediction are magenta (:data:`MISSING_COLOUR`); pixels without ground truth (or
        outside ``mask``) are black.
    """
    disp = np.asarray(disp, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if disp.shape != gt.shape or disp.ndim != 2:
        raise RiverbedError(f"disparity and ground truth differ in shape: {_shape(disp)} vs {_shape(gt)}")
    shown = np.isfinite(gt)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != gt.shape:
            raise RiverbedError(f"mask and ground truth differ in shape: {_shape(mask)} vs {_shape(gt)}")
        shown &= mask
    predicted = shown & np.isfinite(disp)
    err = np.abs(disp[predicted] - gt[predicted])
    bounds = np.array([b for b, _ in ERROR_BINS])
    colours = np.array([c for _, c in ERROR_BINS], np.uint8)
    rgb = np.zeros(gt.shape + (3,), np.uint8)
    # searchsorted(side="left"): an error equal to a bound falls in that bound's bin, (b[i-1], b[i]].
    rgb[predicted] = colours[np.searchsorted(bounds, err, side="left")]
    rgb[shown & ~predicted] = MISSING_COLOUR
    return rgb


def _shape(a):
    return "x".join(str(n) for n in np.shape(a))


def write_png(path, rgb, overwrite=False):
    """Write an RGB (``H x W x 3``) or grey (``H x W``) ``uint8`` image as PNG, atomically.

    Raises
    ------
    RiverbedError
        The path does not end in ``.png``, it exists and ``overwrite`` is false, its folder is missing, or the
        encoder fails.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        shown = path.suffix or "(no extension)"
        raise RiverbedError(f"image output must be a .png file, not '{shown}'", path)
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or not (rgb.ndim == 2 or (rgb.ndim == 3 and rgb.shape[2] == 3)):
        raise RiverbedError(f"PNG output needs uint8 HxW or HxWx3, got {rgb.dtype} {rgb.shape}", path)
    with atomic_output(path, overwrite) as tmp:
        write_png_file(tmp, rgb)


# -- pictures with a legend ------------------------------------------------------------------------------------------

#: Layout of a picture, in pixels: margin, height of the title strip, size of the legend panel beside the map.
PAD = 10
TITLE_HEIGHT = 30
PANEL_WIDTH = 180
PANEL_HEIGHT = (240, 420)  # the panel follows the map's height within these bounds
_DPI = 100
_FONT = 10  # points
_SMALL = 8
_NOTE = 18  # pixels per note line in the panel


@dataclass(frozen=True)
class Picture:
    """A picture riverbed writes: a map at 1:1 pixel scale with a title above it and a legend beside it.

    Attributes
    ----------
    rgb : ndarray of uint8, ``H x W x 3``
        The whole picture, RGB.
    title : str
        The title drawn above the map: what it shows, its units and the metric values.
    box : tuple of int
        ``(row, col, rows, cols)``: where the map's pixels are in ``rgb``, unscaled.
    """

    rgb: np.ndarray
    title: str
    box: tuple

    @property
    def data(self):
        """The map's pixels (``rows x cols x 3``), exactly as colour-mapped."""
        r, c, h, w = self.box
        return self.rgb[r:r + h, c:c + w]


def _number(value, spec):
    return "n/a" if value is None or not np.isfinite(value) else format(value, spec)


def _render(width, height, draw):
    """Render ``draw(fig)`` on a white ``width x height`` px matplotlib figure; returns RGB ``uint8``.

    matplotlib is imported here, not at module import, and drawn with its Agg canvas directly, so the user's
    pyplot backend is left alone and commands that write no picture never import it.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI, facecolor="white")
    canvas = FigureCanvasAgg(fig)
    draw(fig)
    canvas.draw()
    buf = np.asarray(canvas.buffer_rgba())[..., :3]
    out = np.full((height, width, 3), 255, np.uint8)  # the canvas may round its size down by a pixel
    out[: buf.shape[0], : buf.shape[1]] = buf[:height, :width]
    return out


def _text_width(text, size):
    """Width of ``text`` at ``size`` points in pixels."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(1, 1), dpi=_DPI)
    canvas = FigureCanvasAgg(fig)
    t = fig.text(0, 0, text, fontsize=size)
    return int(np.ceil(t.get_window_extent(canvas.get_renderer()).width))


def _colour_bar(cmap, norm, label, extend="neither", ticks=None, tick_labels=None, spacing="uniform"):
    """A legend-drawing function: a vertical colour bar labelled with its units."""
    def draw(fig, cax):
        from matplotlib.cm import ScalarMappable

        bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), cax=cax, extend=extend, ticks=ticks,
                           spacing=spacing, extendfrac=0.06)
        if tick_labels is not None:
            bar.set_ticklabels(tick_labels)
        bar.ax.tick_params(labelsize=_SMALL)
        bar.set_label(label, fontsize=_SMALL)
    return draw


def _scale_bar(resolution):
    """A legend-drawing function: a horizontal scale bar of a round length, at the map's 1:1 pixel scale."""
    def draw(fig, cax):
        from matplotlib.patches import Rectangle

        cax.set_axis_off()
        if not resolution or resolution <= 0:
            return
        room = PANEL_WIDTH - 2 * PAD  # pixels available
        length = max((m * 10.0 ** k for k in range(-3, 7) for m in (1, 2, 5) if m * 10.0 ** k / resolution <= room),
                     default=None)
        if length is None:
            return
        W, H = fig.get_size_inches() * _DPI
        px = length / resolution
        x0, y0 = 12, H - PAD - 14
        fig.add_artist(Rectangle((x0 / W, y0 / H), px / W, 6 / H, transform=fig.transFigure, facecolor="black",
                                 edgecolor="none"))
        fig.text(x0 / W, (y0 - 4) / H, f"{length:g} m", fontsize=_SMALL, va="top")
    return draw


def legend_picture(rgb, title, legend, notes=(), legend_height=None):
    """Lay a colour-mapped map out as a picture: title above, the map at 1:1, the legend panel to its right.

    Parameters
    ----------
    rgb : ndarray of uint8, ``H x W x 3``
        The map; its pixels are copied unchanged into the picture.
    title : str
        One line drawn above the map (what it shows, units, metric values).
    legend : callable
        ``legend(fig, cax)`` draws the legend (a colour bar or a scale bar) in the panel's axes ``cax``.
    notes : sequence of ``(rgb, text)``
        Colours the legend does not cover, explained beneath it with a swatch (e.g. black = no data).
    legend_height : int, optional
        Pixels the legend needs at the top of the panel, the notes beneath; default: the panel's height above
        the notes (a colour bar as tall as the map, within :data:`PANEL_HEIGHT`).

    Returns
    -------
    Picture
        The picture, its title and where the map is in it. Rendering costs the panel and the title strip only,
        whatever the size of the map.
    """
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise RiverbedError(f"a picture's map must be uint8 HxWx3, got {rgb.dtype} {rgb.shape}")
    H, W = rgb.shape[:2]
    panel_h = int(np.clip(H, *PANEL_HEIGHT))
    width = max(PAD + W + PAD + PANEL_WIDTH, _text_width(title, _FONT) + 2 * PAD)
    height = TITLE_HEIGHT + max(H, panel_h) + PAD

    def draw_title(fig):
        fig.text(PAD / width, 0.5, title, fontsize=_FONT, va="center", ha="left")

    def draw_panel(fig):
        from matplotlib.patches import Rectangle

        notes_top = panel_h - 8 - legend_height if legend_height else PAD + _NOTE * len(notes)  # from the bottom
        cax = fig.add_axes([12 / PANEL_WIDTH, notes_top / panel_h, 16 / PANEL_WIDTH,
                            (panel_h - notes_top - 8) / panel_h])
        legend(fig, cax)
        for k, (colour, text) in enumerate(notes):
            y = notes_top - _NOTE * (k + 1)
            fig.add_artist(Rectangle((12 / PANEL_WIDTH, y / panel_h), 12 / PANEL_WIDTH, 12 / panel_h,
                                     transform=fig.transFigure, facecolor=np.asarray(colour) / 255,
                                     edgecolor="grey", linewidth=0.5))
            fig.text(30 / PANEL_WIDTH, (y + 6) / panel_h, text, fontsize=_SMALL, va="center")

    out = np.full((height, width, 3), 255, np.uint8)
    out[:TITLE_HEIGHT] = _render(width, TITLE_HEIGHT, draw_title)
    out[TITLE_HEIGHT:TITLE_HEIGHT + H, PAD:PAD + W] = rgb
    c = PAD + W + PAD
    out[TITLE_HEIGHT:TITLE_HEIGHT + panel_h, c:c + PANEL_WIDTH] = _render(PANEL_WIDTH, panel_h, draw_panel)
    return Picture(out, title, (TITLE_HEIGHT, PAD, H, W))


def error_map_picture(disp, gt, mask=None, metrics=None):
    """:func:`error_map` with its legend: the error bins in px, bad3 and the mean error in the title.

    Parameters
    ----------
    disp, gt, mask
        As for :func:`error_map` (disparities in pixels, NaN invalid).
    metrics : mapping, optional
        :func:`~riverbed_cli.products.evaluate.evaluate_disparity` of the same pixels (``bad3`` in %, ``avg``
        in px, ``n``); computed over ``mask`` when not given.

    Returns
    -------
    Picture
        Title ``"disparity error |d - gt| (px), bad3 1.92 %, mean 0.28 px, n 365815 px"``; a colour bar of the bins
        (px); swatches for magenta (no prediction) and black (no ground truth, or left out by ``mask``).
    """
    from matplotlib.colors import BoundaryNorm, ListedColormap

    rgb = error_map(disp, gt, mask)
    if metrics is None:
        exclude = None if mask is None else ~np.asarray(mask, dtype=bool)
        metrics = evaluate_disparity(disp, gt, exclude=exclude)
    title = (f"disparity error |d - gt| (px), bad3 {_number(metrics['bad3'], '.2f')} %, "
             f"mean {_number(metrics['avg'], '.2f')} px, n {metrics['n']} px")
    bounds = [0.0] + [b for b, _ in ERROR_BINS[:-1]]
    colours = np.array([c for _, c in ERROR_BINS], float) / 255
    cmap = ListedColormap(colours[:-1]).with_extremes(over=colours[-1])
    labels = ["0", "1/16", "1/8", "1/4", "1/2", "1", "2", "4", "8", "16"]
    legend = _colour_bar(cmap, BoundaryNorm(bounds, cmap.N), "|d - gt| (px)", "max", bounds,
                         labels)
    return legend_picture(rgb, title, legend, [(MISSING_COLOUR, "no prediction (bad)"),
                                               ((0, 0, 0), "no GT, or left out")])


def difference_picture(dsm, ref, metrics=None, limit=None):
    """The DSM difference map ``dz = dsm - ref`` with its legend: a colour bar in m, median and NMAD in the title.

    Parameters
    ----------
    dsm, ref : array_like, ``H x W``
        Heights (m) on one grid, NaN no data.
    metrics : mapping, optional
        :func:`~riverbed_cli.products.dsm_compare.compare_dsm` of the two (m, %); computed when not given.
    limit : float, optional
        |dz| (m) at which the colours saturate; default
        :func:`~riverbed_cli.products.dsm_compare.difference_limit`.

    Returns
    -------
    Picture
        The pixels of :func:`~riverbed_cli.products.dsm_compare.difference_map` (blue below, white equal, red
        above the reference, black where either has no data) under a title with the median, NMAD, RMSE and
        completeness.
    """
    from matplotlib.colors import LinearSegmentedColormap, Normalize

    if limit is None:
        limit = difference_limit(dsm, ref)
    rgb = difference_map(dsm, ref, limit)
    if metrics is None:
        metrics = compare_dsm(dsm, ref)
    title = (f"DSM - reference dz (m), median {_number(metrics['median'], '+.3f')} m, "
             f"NMAD {_number(metrics['nmad'], '.3f')} m, RMSE {_number(metrics['rmse'], '.3f')} m, "
             f"completeness {_number(metrics['completeness'], '.1f')} %")
    cmap = LinearSegmentedColormap.from_list("dz", [(0, 0, 1), (1, 1, 1), (1, 0, 0)], N=256)
    legend = _colour_bar(cmap, Normalize(-limit, limit), f"dz (m), saturates at ±{limit:.3g} m", "both")
    return legend_picture(rgb, title, legend, [((0, 0, 0), "no data in either")])


def disparity_picture(disp, vmin=None, vmax=None):
    """:func:`colorize_disparity` with its legend: a Turbo colour bar in px, the share matched in the title.

    Parameters
    ----------
    disp : array_like, ``H x W``
        Disparity in pixels, NaN invalid.
    vmin, vmax : float, optional
        As for :func:`colorize_disparity` (default: the finite minimum and maximum).

    Returns
    -------
    Picture
        Title ``"disparity d = x_left - x_right (px), 99.2 % matched, 4.0 .. 25.4 px"``; black = no match.
    """
    from matplotlib.colors import ListedColormap, Normalize

    disp = np.asarray(disp, dtype=np.float64)
    rgb = colorize_disparity(disp, vmin, vmax)
    valid = np.isfinite(disp)
    share = 100.0 * valid.mean() if disp.size else 0.0
    title = f"disparity d = x_left - x_right (px), {share:.1f} % matched"
    if valid.any():
        lo = float(disp[valid].min()) if vmin is None else float(vmin)
        hi = float(disp[valid].max()) if vmax is None else float(vmax)
        title += f", {lo:.1f} .. {hi:.1f} px"
    else:
        lo, hi = 0.0, 1.0
    turbo = cv2.cvtColor(cv2.applyColorMap(np.arange(256, dtype=np.uint8)[None], cv2.COLORMAP_TURBO),
                         cv2.COLOR_BGR2RGB)[0]
    legend = _colour_bar(ListedColormap(turbo / 255.0), Normalize(lo, hi if hi > lo else lo + 1.0),
                         "disparity (px), high = near")
    return legend_picture(rgb, title, legend, [((0, 0, 0), "no match")])


def hillshade_picture(shade, dsm, resolution, azimuth=315.0, altitude=45.0):
    """A DSM hillshade with its legend: the height range and cell size in the title, a scale bar in m.

    Parameters
    ----------
    shade : ndarray of uint8, ``H x W``
        The hillshade (:func:`~riverbed_cli.products.dsm.hillshade`), 0 where the DSM has no data.
    dsm : array_like, ``H x W``
        The DSM it shades (m, NaN no data): for the height range.
    resolution : float
        Cell size (m): for the title and the scale bar.
    azimuth, altitude : float
        The sun the hillshade was computed for (degrees), for the title.

    Returns
    -------
    Picture
        The grey shaded relief, ``shade`` in all three channels, under a title such as
        ``"DSM hillshade (sun 315° az, 45° alt), height 0.00 .. 30.00 m, 0.4 m cells"``.
    """
    shade = np.asarray(shade)
    z = np.asarray(dsm, np.float64)
    if shade.dtype != np.uint8 or shade.ndim != 2 or shade.shape != z.shape:
        raise RiverbedError(f"hillshade must be uint8 HxW like the DSM, got {shade.dtype} {_shape(shade)} for a "
                            f"{_shape(z)} DSM")
    ok = np.isfinite(z)
    heights = f"{z[ok].min():.2f} .. {z[ok].max():.2f} m" if ok.any() else "no data"
    title = (f"DSM hillshade (sun {azimuth:g}° az, {altitude:g}° alt), height {heights}, "
             f"{resolution:g} m cells")
    return legend_picture(np.repeat(shade[:, :, None], 3, axis=2), title, _scale_bar(resolution),
                          [((0, 0, 0), "no data")], legend_height=40)


def write_picture(path, picture, overwrite=False):
    """Write a :class:`Picture` as PNG, atomically (the rules of :func:`write_png`)."""
    write_png(path, picture.rgb, overwrite=overwrite)

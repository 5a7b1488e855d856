# %% [markdown]
# # A tutorial on real images: Pleiades over Mont Ventoux
#
# The whole chain a user runs on a stereo pair, on real Pleiades 1B images: tie points
# (`match`), a bundle adjustment of the vendor RPCs from the ties alone (`adjust`), an
# orthoimage (`ortho`), a DSM (`dsm`) and its co-registration onto a reference DEM
# (`coregister`). Each step calls the library function that the `jaxgeo` command calls
# (named in each section, with the command beside it), prints the numbers to expect on these
# images and shows the picture a person judges the step by, with how to read it.
#
# **The data.** Two crops of a Pleiades 1B along-track stereo pair over the lower north-western
# slopes of Mont Ventoux (France), 2013-08-05, 33 s apart: `left_image.tif` (500 x 500 px) and
# `right_image.tif` (498 x 495 px), panchromatic, 0.5 m; the OSSIM `.geom` RPCs of the
# **full products** (the crops carry their origin in the product as a pixel-space
# geotransform); the SRTM 3" tile N44E005 (EGM96 heights) and a crop of the EGM96 geoid grid.
# They come from the test data of CNES **shareloc** (https://github.com/CNES/shareloc),
# copyright CNES, licence **Apache-2.0** (the licence text is `tests/data/LICENSE-shareloc.txt`),
# vendored unchanged in `tests/data/real/ventoux/` and `tests/data/real/phr_ventoux__*.geom`;
# their provenance, file by file, is in
# [`tests/data/real/ventoux/README.md`](../tests/data/real/ventoux/README.md).
#
# The notebook takes about a minute of CPU time, most of it compiling (the time is printed at
# the end); it writes its files in a temporary folder, removed at the end. The commands can
# also write each step's figures as one self-contained HTML page, not shown here:
# `jaxgeo adjust ... -o adjusted --report` writes `adjusted/report.html`, `jaxgeo dsm ... -o
# dsm.tif --report` writes `dsm.report.html` beside the DSM (`jaxgeo.report.write_*_report`).

# %%
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time
import warnings

import matplotlib.pyplot as plt
import numpy as np
import pyproj
import rasterio
from matplotlib.colors import LightSource
from scipy.ndimage import binary_erosion, distance_transform_edt, generic_filter

import jaxgeo
from jaxgeo.bundle import AdjustSettings, adjust_files
from jaxgeo.coreg import CoregistrationError, NuthKaab, coregister, dh_stats
from jaxgeo.intersect import intersect
from jaxgeo.io import open_image, read_dem
from jaxgeo.ortho import OrthoSettings, orthorectify
from jaxgeo.stereo import (
    DSMSettings,
    MatchSettings,
    adjustment_covariance,
    epipolar_offsets,
    make_dsm,
    match_images,
)
from jaxgeo.tiles import TileSettings

T0, C0 = time.perf_counter(), time.process_time()
REAL = pathlib.Path(jaxgeo.__file__).parents[1] / "tests/data/real"  # a clone of the repository
VENTOUX = REAL / "ventoux"
WORK = pathlib.Path(tempfile.mkdtemp(prefix="jaxgeo-nb06-"))
NAMES = ("left_image", "right_image")
QUIET = TileSettings(progress=False)  # no progress bars in the notebook's outputs


def num(x):
    """``x`` (a number or an array) rounded to 4 significant digits, for ``key_numbers``."""
    a = np.asarray(x, dtype=float)
    return float(f"{a:.4g}") if a.ndim == 0 else [num(v) for v in a]


def rms(v):
    return float(np.sqrt(np.nanmean(np.square(v))))


# printed as one line at the end (tests/notebooks/test_notebook_06.py reads it)
key_numbers = {}

# %% [markdown]
# ## 1. The images, their models and the DEM
#
# `jaxgeo.io.open_image` reads a raster with its sensor model and its pixel frame, as every
# command does (`--model IMG=FILE`): here the product's `.geom` RPC and the crop's origin from
# its pixel-space geotransform, so that pixel `(0, 0)` of the crop is the product's pixel
# `(5000, 5000)` for the left image. `jaxgeo.io.read_dem` reads SRTM with its datum:
# SRTM's heights are above the EGM96 geoid, jaxgeo works in ellipsoidal heights, and the
# geoid grid given turns one into the other (`--dem srtm.tif --geoid egm96`; the geoid grid
# shipped with jaxgeo would do as well: `geoid="egm96"`). Forgetting the geoid is the
# classic error: the undulation (printed below) in height, metres on the ground (the
# documentation's page "DEMs and geoids", `docs/dems.md`).

# %%
images = [open_image(VENTOUX / f"{n}.tif", model=REAL / f"phr_ventoux__{n}.geom") for n in NAMES]
dem = read_dem(VENTOUX / "dem/N44E005_srtm90.tif",
               geoid=VENTOUX / "dem/egm96_15_crop_lon3-8_lat42-47.gtx")  # fmt: skip
for im in images:
    print(f"{im.name}: {im.size[0]} x {im.size[1]} px, origin in the product "
          f"{im.origin}, model {type(im.model).__name__} from {im.model_path.name}")  # fmt: skip
print(dem.describe())
centre = np.array([[5.195, 44.206]])  # lon, lat (deg): the crops
raw = read_dem(VENTOUX / "dem/N44E005_srtm90.tif", height="ellipsoidal")  # the file's values
geoid_m = float(dem(centre)[0] - raw(centre)[0])
print(f"the geoid undulation there: {geoid_m:+.1f} m (SRTM's height + it = ellipsoidal height)")
key_numbers["geoid_m"] = num(geoid_m)

# %% [markdown]
# ## 2. Tie points: `match_images` (`jaxgeo match`)
#
# SIFT keypoints of the left image searched near the epipolar curves the RPCs predict in the
# right one, between the heights of the DEM over the footprint (+-50 m), then verified (one
# tie per keypoint, no ambiguous match, an offset across the epipolar curves like the
# pair's, a height inside the range and like its neighbours'). The summary below is what
# `jaxgeo match` prints.

# %%
t = time.perf_counter()
ties = match_images(images, MatchSettings(), dem=dem)
t_match = time.perf_counter() - t
(pair,) = ties.pairs
print("\n".join(pair.summary()))
ties.write(WORK / "ties.csv")
obs = ties.observations
xy = {n: obs.xy[np.array(obs.images) == n] for n in NAMES}  # the same points, in the same order
print(f"{ties.describe()}; {t_match:.1f} s")
key_numbers["match"] = {
    "ties": pair.n_kept,
    "candidates": pair.n_candidates,
    "across_px": num(pair.across_px),
    "across_sigma_px": num(pair.across_sigma_px),
    "heights_m": num(pair.heights_m),
}

# %% [markdown]
# What to expect: 689 ties kept of 907 candidates, the rejections named by check; tie heights
# from 514 to 561 m (5th to 95th percentile, ellipsoidal). The **offset across the epipolar
# curves, -4.75 px**, with a spread of only 0.33 px over the ties, is the relative pointing
# error of the two delivered RPCs: every tie lies 4.75 px off the curve its partner predicts,
# consistently. That is what the adjustment takes out. The ties lie where both crops see the
# ground: the right crop overlaps only the bottom of the left one (the crops were cut for
# shareloc's tests, not as a stereo pair), a band along the bottom of the left image.

# %%
fig, axes = plt.subplots(1, 2, figsize=(10, 5), dpi=72)  # quicklooks: texture weighs
for ax, im in zip(axes, images, strict=True):
    with rasterio.open(im.path) as f:
        pixels = f.read(1)
    lo, hi = np.percentile(pixels, [1, 99])
    ax.imshow(pixels, cmap="gray", vmin=lo, vmax=hi)
    ax.plot(*xy[im.name].T, "+", color="tab:orange", ms=4, label=f"{len(xy[im.name])} ties")
    ax.set(title=im.name, xlabel="column (px)", ylabel="row (px)")
    ax.legend(loc="upper right")
fig.tight_layout()
plt.show()

# %% [markdown]
# ## 3. Bundle adjustment from the ties: `adjust_files` (`jaxgeo adjust`)
#
# No GCP: a relative orientation. Each image gets a bias shift (`--bias shift`: two
# unknowns, a constant offset in column and row); priors of 10 px hold the block near the
# delivered models' absolute position (the note says so); the DEM gives every tie a height
# observation (`AdjustSettings(tie_height=dem)`, i.e. `--dem srtm.tif --geoid egm96`), which
# fixes the part the ties cannot see: the relative shift along the epipolar direction,
# which moves the heights and nothing else. The loss is robust and gross errors are snooped
# (the defaults). The command-line equivalent:
#
# ```bash
# jaxgeo adjust left_image.tif right_image.tif --model left_image=phr_ventoux__left_image.geom \
#     --model right_image=phr_ventoux__right_image.geom --observations ties.csv --bias shift \
#     --dem N44E005_srtm90.tif --geoid egm96 -o adjusted
# ```

# %%
t = time.perf_counter()
run = adjust_files(dict(zip(NAMES, images, strict=True)), WORK / "ties.csv", bias="shift",
                   settings=AdjustSettings(tie_height=dem))  # fmt: skip
t_adjust = time.perf_counter() - t
result = run.result
print(run.format())
run.write(WORK / "adjusted")  # RPCs, adjusted_models.json, report.txt/json, residuals.csv
print(f"\n{t_adjust:.1f} s; wrote {sorted(p.name for p in (WORK / 'adjusted').iterdir())}")

# %% [markdown]
# The shifts and what they mean on the ground. Without GCPs only the **relative** shift
# (right minus left) is determined by the data; the absolute one stays at the delivered
# models' (its sigma, 4.3 px, is the prior's), so the adjustment splits the relative shift
# between the two images. In metres: the ground displacement of each crop's centre, localised
# at the ties' median height with the delivered and with the adjusted model.

# %%
params = {n: np.array([result.parameters(n)[f".bias.shift_px[{k}]"][0] for k in (0, 1)])
          for n in NAMES}  # fmt: skip
cov = adjustment_covariance(result, list(NAMES))  # (left x, left y, right x, right y), px^2
relative = params["right_image"] - params["left_image"]
d = np.array([[-1.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 1.0]])
relative_sigma = np.sqrt(np.diag(d @ cov @ d.T))
adjusted = [open_image(im.path, model=WORK / "adjusted/adjusted_models.json") for im in images]
h_ties = pair.heights_m[1]  # median tie height (ellipsoidal m)
to_utm = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True)
moved_m = {}
for given, new in zip(images, adjusted, strict=True):
    centre = np.array([[(given.size[0] - 1) / 2, (given.size[1] - 1) / 2]])
    en = [np.array(to_utm.transform(*np.asarray(m.localize(centre, np.array([h_ties])))[0, :2]))
          for m in (given.model, new.model)]  # fmt: skip
    moved_m[given.name] = en[1] - en[0]
    print(f"{given.name}: shift ({params[given.name][0]:+.2f}, {params[given.name][1]:+.2f}) px "
          f"+- {np.sqrt(cov[0, 0]):.1f} px (absolute): the image moves on the ground by "
          f"({moved_m[given.name][0]:+.2f} E, {moved_m[given.name][1]:+.2f} N) m")  # fmt: skip
length = np.linalg.norm(relative)
print(f"relative shift right - left: ({relative[0]:+.2f}, {relative[1]:+.2f}) px "
      f"+- ({relative_sigma[0]:.3f}, {relative_sigma[1]:.3f}) px, "
      f"{length:.2f} px = {length * 0.5:.1f} m at 0.5 m GSD")  # fmt: skip

# %% [markdown]
# **Residuals before and after.** The same measure for both: each tie intersected from its
# two rays (`jaxgeo.intersect.intersect`, no DEM), once with the delivered models and once
# with the adjusted ones; the residual is the intersected point projected back minus the
# measured position. With two rays a tie has one redundant coordinate: its residual lies
# across the epipolar curve, equal and opposite in the two images. The offset across the
# epipolar curves (`jaxgeo.stereo.epipolar_offsets`, what a dense matcher working along
# epipolar lines suffers) is the same error seen from one image.


# %%
def tie_residuals(models):
    """``{image: (n, 2) px}``: intersect the ties from their two rays, project back."""
    both = np.stack([xy[n] for n in NAMES], axis=1)  # (n, 2 images, 2)
    out = np.asarray(intersect(models, both).residuals_px)
    return {n: out[:, i] for i, n in enumerate(NAMES)}


h_range = (pair.height_range_m[0], pair.height_range_m[1])
residuals, across = {}, {}
for kind, ims in (("before", images), ("after", adjusted)):
    models = [im.model for im in ims]
    residuals[kind] = tie_residuals(models)
    across[kind] = np.asarray(epipolar_offsets(*models, xy[NAMES[0]], xy[NAMES[1]], h_range))
    r = residuals[kind]
    print(f"{kind:6s}: " + ", ".join(
        f"{n} RMS ({rms(r[n][:, 0]):.2f}, {rms(r[n][:, 1]):.2f}) px" for n in NAMES)
        + f"; across the epipolar curves: median {np.median(across[kind]):+.2f} px, "
        f"RMS {rms(across[kind]):.2f} px")  # fmt: skip
# with two rays a tie's residual can only lie across the epipolar curve (one redundant
# coordinate), equal and opposite in the two images: its signed length along that direction
u = np.median(residuals["before"][NAMES[0]], axis=0)
u /= np.linalg.norm(u)
signed = {kind: residuals[kind][NAMES[0]] @ u for kind in ("before", "after")}
print("signed residual across the epipolar curve (left image): " + ", ".join(
    f"{k} {np.mean(v):+.2f} +- {np.std(v):.2f} px" for k, v in signed.items()))  # fmt: skip
own = {n: result.residuals_px[np.array(result.observation_images) == n] for n in NAMES}
print("the adjustment's own residuals (with the DEM heights): " + ", ".join(
    f"{n} RMS ({rms(own[n][:, 0]):.2f}, {rms(own[n][:, 1]):.2f}) px" for n in NAMES)
    + f"; s0 {result.s0:.2f} with the a priori 0.5 px")  # fmt: skip
key_numbers["adjust"] = {
    "s0": num(result.s0),
    "converged": bool(result.converged),
    "shift_px": {n: num(params[n]) for n in NAMES},
    "absolute_sigma_px": num(np.sqrt(cov[0, 0])),
    "relative_px": num(relative),
    "relative_sigma_px": num(relative_sigma),
    "moved_m": {n: num(moved_m[n]) for n in NAMES},
    "rms_before_px": {n: num([rms(residuals["before"][n][:, k]) for k in (0, 1)]) for n in NAMES},
    "rms_after_px": {n: num([rms(residuals["after"][n][:, k]) for k in (0, 1)]) for n in NAMES},
    "across_before_px": num(np.median(across["before"])),
    "across_after_px": num(np.median(across["after"])),
    "across_rms_after_px": num(rms(across["after"])),
    "signed_px": {k: num([np.mean(v), np.std(v)]) for k, v in signed.items()},
}

# %%
fig, axes = plt.subplot_mosaic([["left_image before", "right_image before", "hist"],
                                ["left_image after", "right_image after", "hist"]],
                               figsize=(16, 9.5), width_ratios=[1, 1, 0.9], dpi=72)  # fmt: skip
scale = {"before": 10.0, "after": 100.0}  # arrows: px of image per px of residual
for kind in ("before", "after"):
    for im in images:
        ax, r, size = axes[f"{im.name} {kind}"], residuals[kind][im.name], im.size
        ax.add_patch(plt.Rectangle((-0.5, -0.5), size[0], size[1], fill=False, lw=0.8))
        q = ax.quiver(*xy[im.name].T, *r.T, angles="xy", scale_units="xy", scale=1 / scale[kind],
                      color="tab:red" if kind == "before" else "tab:blue", width=0.003)  # fmt: skip
        key = 2.0 if kind == "before" else 0.2
        ax.quiverkey(q, 0.6, 0.5, key, f"{key:g} px (drawn x{scale[kind]:g})", labelpos="N")
        ax.set(xlim=(-10, size[0] + 10), ylim=(size[1] + 10, -10), aspect="equal",
               title=f"{im.name}, {kind}: RMS {rms(np.linalg.norm(r, axis=1)):.2f} px",
               xlabel="column (px)",
               ylabel="row (px)")  # fmt: skip
ax = axes["hist"]
bins = np.linspace(-1.0, 3.2, 85)
for kind, colour in (("before", "tab:red"), ("after", "tab:blue")):
    v = signed[kind]
    ax.hist(v, bins=bins, color=colour, alpha=0.6,
            label=f"{kind}: {np.mean(v):+.2f} +- {np.std(v):.2f} px")  # fmt: skip
ax.set(xlabel="residual across the epipolar curve, left image (px)", ylabel="ties",
       title="signed residuals, before and after")  # fmt: skip
ax.legend(loc="upper right")
fig.tight_layout()
plt.show()

# %% [markdown]
# **How to read it.** One arrow per tie, at its position in the frame, from the measured
# position to the intersected point's projection, magnified (10 times before, 100 times
# after: see the key). Before (red), every arrow has the same direction and about the same
# length, over the whole overlap: a systematic error, the signature of a relative bias of the
# RPCs, not of bad ties (matching noise has both signs and all lengths). A bias shift is the
# right model when the arrows are parallel and equal over the whole frame; arrows that turn or
# grow across the frame call for `--bias affine` (rotation, scale), waves along the rows for
# `--bias jitter`. After (blue), the arrows have both signs and random lengths, a tenth of
# before's: what is left is noise. The histogram (signed, across the epipolar curve) says it
# in one picture: the peak moves from +2.39 px to 0.00 px and keeps its width (0.18 px): the
# error removed was a constant. A tie far from the peak after the adjustment would be a gross
# error; the adjustment's report names those (none here).
#
# The numbers to expect: with the delivered models the ties miss by (2.32, 0.62) px RMS
# (column, row) in the left image and (2.33, 0.64) px in the right one; after, (0.17, 0.05)
# and (0.18, 0.05) px. The offset across the epipolar curves falls from -4.75 px to +0.03 px
# (median). The relative shift found is (+3.89, +3.98) px, to +-(0.05, 0.18) px, 5.57 px or
# 2.8 m; it is split between the images, (-1.97, -1.95) px left and (+1.92, +2.03) px right,
# each moving by about 1.4 m on the ground, in opposite directions. The adjustment's own
# residuals, with the DEM's height for every tie as well, are the same (0.18, 0.05) px; its s0
# is 0.61 with the a priori sigma of 0.5 px: the ties are matched to about 0.3 px.

# %% [markdown]
# ## 4. The orthoimage: `orthorectify` (`jaxgeo ortho`)
#
# The left image with its adjusted model (`adjusted_models.json`, as
# `--model left_image=adjusted/adjusted_models.json`) on SRTM, at the image's GSD rounded
# (0.5 m) in the local UTM zone (EPSG:32631), the pixels on multiples of the resolution. The
# ties are drawn at their adjusted ground positions, and the area the right image also sees
# is outlined: it is where the DSM can have heights.

# %%
t = time.perf_counter()
ortho = orthorectify(adjusted[0], dem, WORK / "left_ortho.tif", OrthoSettings(), QUIET)
t_ortho = time.perf_counter() - t
print(f"{ortho.width} x {ortho.height} px of {ortho.res_m:g} m ({ortho.crs}); "
      f"{ortho.valid_fraction:.1%} with data; grid error left {ortho.grid_error_px:.1g} px; "
      f"GSD {ortho.gsd:.3f} m; {t_ortho:.1f} s")  # fmt: skip
with rasterio.open(ortho.path) as f:
    quick, ortho_extent, nodata = f.read(1).astype(float), f.bounds, f.nodata
quick[quick == nodata] = np.nan
tie_rows = [result.point_ids.index(p) for p in dict.fromkeys(obs.point_ids)]
tie_en = np.array(to_utm.transform(*result.ground[tie_rows, :2].T)).T


def seen_by_both(east, north):
    """Whether the ground at UTM ``east, north`` (on SRTM) lies inside both crops."""
    lon, lat = pyproj.Transformer.from_crs("EPSG:32631", "EPSG:4326",
                                           always_xy=True).transform(east, north)  # fmt: skip
    ground = np.stack([lon, lat, dem(np.stack([lon, lat], -1))], -1).reshape(-1, 3)
    inside = np.ones(len(ground), bool)
    for im in adjusted:
        p = np.asarray(im.model.project(ground))
        inside &= np.all((p >= -0.5) & (p <= np.array(im.size) - 0.5), axis=1)
    return inside.reshape(np.shape(east))


key_numbers["ortho"] = {
    "size_px": [ortho.width, ortho.height],
    "res_m": ortho.res_m,
    "valid_fraction": num(ortho.valid_fraction),
    "gsd_m": num(ortho.gsd),
}

# %%
fig, ax = plt.subplots(figsize=(7.5, 7.2), dpi=72)
extent = (ortho_extent.left, ortho_extent.right, ortho_extent.bottom, ortho_extent.top)
lo, hi = np.nanpercentile(quick, [1, 99])
ax.imshow(quick, cmap="gray", vmin=lo, vmax=hi, extent=extent)
e_grid, n_grid = np.meshgrid(np.linspace(extent[0], extent[1], 200),
                             np.linspace(extent[2], extent[3], 200))  # fmt: skip
ax.contour(e_grid, n_grid, seen_by_both(e_grid, n_grid).astype(float), levels=[0.5],
           colors="tab:cyan", linewidths=1.5)  # fmt: skip
ax.plot(*tie_en.T, "+", color="tab:orange", ms=4, label=f"{len(tie_en)} ties (adjusted)")
ax.plot([], [], color="tab:cyan", label="seen by both images")
ax.set(title=f"left_image ortho, {ortho.res_m:g} m, {ortho.valid_fraction:.1%} with data",
       xlabel="east (m, UTM 31N)", ylabel="north (m)")  # fmt: skip
ax.ticklabel_format(useOffset=False, style="plain")
ax.legend(loc="upper right")
fig.tight_layout()
plt.show()

# %% [markdown]
# **How to read it.** North is up: the crop, a square in the image, lands as a slightly
# rotated quadrilateral (the satellite's track and look angle); the white corners are outside
# the image (no data), hence 90.5 % of the 533 x 514 px grid with data. Paths and the edges of
# the clearings should be continuous where they are on the ground: a kink along a line would
# be a DEM error (SRTM's 90 m cells smooth the ravines) or a model error. The ties, placed at
# their adjusted ground positions, sit inside the outline of the area seen by both images:
# what falls outside it would be a tie matched on the wrong feature, or a model placing the
# image wrongly. The image's GSD is 0.499 m, hence the 0.5 m pixels.

# %% [markdown]
# ## 5. The DSM: `make_dsm` (`jaxgeo dsm`)
#
# The pair with the adjusted models, epipolar rectification, dense matching (OpenCV's SGM),
# triangulation, at 1 m cells (`DSMSettings(res_m=1.0)`, `--res 1`; the default 0.5 m has four times
# the cells). The orientation's posterior covariance
# (`adjustment_covariance`, what `--orientation adjusted/adjusted_models.json` reads) goes
# into the `height_sigma` band. A second DSM from the delivered models is made for the
# comparisons below (its `height_sigma` holds the vendor models' a priori 0.7 px instead).

# %%
cov_orientation = adjustment_covariance(result, list(NAMES))
dsms = {}
t = time.perf_counter()
dsms["adjusted"] = make_dsm(adjusted, WORK / "dsm_adjusted.tif", DSMSettings(res_m=1.0), QUIET,
                            dem=dem, orientation=cov_orientation)  # fmt: skip
# the same grid for both (`--like`): their cells can be compared one by one
same_grid = DSMSettings(like=WORK / "dsm_adjusted.tif")
dsms["delivered"] = make_dsm(images, WORK / "dsm_delivered.tif", same_grid, QUIET, dem=dem)
t_dsm = time.perf_counter() - t
report = dsms["adjusted"]
print(report.summary(str(report.path)))
print(f"(delivered models: {dsms['delivered'].filled:.1%} with a height, median height_sigma "
      f"{dsms['delivered'].median_height_sigma_m:.2f} m; both DSMs {t_dsm:.1f} s)")  # fmt: skip
with rasterio.open(report.path) as f:
    bands = dict(zip(f.descriptions, f.read(), strict=True))
    dsm_transform, dsm_shape = f.transform, (f.height, f.width)
height, sigma = bands["height"], bands["height_sigma"]
rows, cols = np.indices(dsm_shape)
east = dsm_transform.c + (cols + 0.5) * dsm_transform.a
north = dsm_transform.f + (rows + 0.5) * dsm_transform.e
both = seen_by_both(east, north)
has = np.isfinite(height)
print(f"the grid covers the left image's footprint: {both.mean():.1%} of its cells are seen by "
      f"both images; of those, {has[both].mean():.1%} have a height "
      f"({bands['filled'][has].mean():.1%} of the heights interpolated, "
      "band 'filled')")  # fmt: skip
# a cell against the median of its 9 x 9 neighbours, at the DSM's edges (3 cells) and inside
with warnings.catch_warnings():
    warnings.simplefilter("ignore", RuntimeWarning)  # windows without any height
    local = generic_filter(height, np.nanmedian, size=9, mode="constant", cval=np.nan)
edge = has & ~binary_erosion(has, iterations=3)
outliers = {}
for where, cells in (("edge", edge), ("inside", has & ~edge)):
    off = (height - local)[cells]
    big = np.abs(off) > 5.0
    outliers[where] = {"fraction": num(big.mean()), "cells": int(cells.sum()),
                       "count": int(big.sum())}  # fmt: skip
    print(f"{where:6s}: {big.mean():.2%} of {cells.sum()} cells ({big.sum()}) more than 5 m from "
          "their neighbours' median")  # fmt: skip
# the empty ring: the share of the overlap's cells with a height, by their distance (cells of
# 1 m) from the overlap's edge, where one image's data ends
depth = distance_transform_edt(both)
profile = [float(has[both & (depth > k - 1) & (depth <= k)].mean()) for k in range(1, 16)]
deep = both & (depth > 15)
ring_m = int(np.argmax(np.array(profile) >= 0.05))  # the metres next to the edge (< 5 % filled)
print("cells with a height, by distance from the overlap's edge (m): " + ", ".join(
    f"{k} {v:.0%}" for k, v in enumerate(profile[:10], start=1))
    + f"; beyond 15 m {has[deep].mean():.1%}")  # fmt: skip
ring = both & (depth <= ring_m)
print(f"the first {ring_m} m (under 5 % with a height): {ring.mean() / both.mean():.1%} of the "
      f"overlap's cells, {(ring & ~has).sum() / (both & ~has).sum():.0%} of its holes")  # fmt: skip
key_numbers["dsm"] = {
    "res_m": report.res_m,
    "shape": list(dsm_shape),
    "filled": num(report.filled),
    "overlap_fraction": num(both.mean()),
    "filled_in_overlap": num(has[both].mean()),
    "interpolated_of_heights": num(bands["filled"][has].mean()),
    "outliers": outliers,
    "fill_by_edge_distance": num(profile),
    "fill_beyond_15m": num(has[deep].mean()),
    "ring_m": ring_m,
    "holes_in_ring": num((ring & ~has).sum() / (both & ~has).sum()),
    "ring_share": num(ring.mean() / both.mean()),
    "median_sigma_m": num(report.median_height_sigma_m),
    "median_sigma_delivered_m": num(dsms["delivered"].median_height_sigma_m),
    "height_p5_p50_p95_m": num(np.percentile(height[has], [5, 50, 95])),
}

# %%
fig, axes = plt.subplots(4, 1, figsize=(10, 14), height_ratios=[1, 1, 1, 0.8], dpi=72)
window = np.ix_(np.any(both, axis=1), np.any(both, axis=0))  # the cells seen by both images
dsm_extent = (east[window].min() - 0.5, east[window].max() + 0.5,
              north[window].min() - 0.5, north[window].max() + 0.5)  # fmt: skip
shade = LightSource(azdeg=315, altdeg=30).hillshade(
    np.nan_to_num(height, nan=np.nanmedian(height)), vert_exag=2, dx=1.0, dy=1.0)  # fmt: skip
shade[~binary_erosion(has)] = np.nan  # a cell beside a hole has no slope
holes = both & ~has
axes[0].imshow(shade[window], cmap="gray", extent=dsm_extent)
axes[0].imshow(np.where(holes, 1.0, np.nan)[window], cmap="autumn", extent=dsm_extent)
interpolated = has & (bands["filled"] > 0)
axes[0].imshow(np.where(interpolated, 1.0, np.nan)[window], cmap="cool", extent=dsm_extent)
axes[0].set(title=f"hillshade (light from the north-west, heights x2); red: no height "
                  f"({holes[both].mean():.1%} of the overlap), cyan: interpolated")  # fmt: skip
im = axes[1].imshow(height[window], cmap="terrain", extent=dsm_extent)
fig.colorbar(im, ax=axes[1], label="height (m, ellipsoidal)")
axes[1].set(title="height")
im = axes[2].imshow(sigma[window], cmap="magma", extent=dsm_extent, vmin=0, vmax=2)
fig.colorbar(im, ax=axes[2], label="height_sigma (m)", extend="max")
axes[2].set(title=f"height_sigma, median {report.median_height_sigma_m:.2f} m")
for ax in axes[:3]:
    ax.set(xlabel="east (m, UTM 31N)", ylabel="north (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
axes[3].plot(range(1, 16), 100 * np.array(profile), "o-", color="tab:red")
axes[3].axhline(100 * has[deep].mean(), color="gray", ls="--", label="beyond 15 m")
axes[3].axvspan(0.5, ring_m + 0.5, color="tab:red", alpha=0.1,
                label="the ring: matching windows that meet no data")  # fmt: skip
axes[3].set(xlabel="distance from the edge of the overlap (m, 1 m cells)",
            ylabel="cells with a height (%)", ylim=(0, 100), xlim=(0.5, 15.5),
            title="the overlap's cells with a height, by distance from its edge")  # fmt: skip
axes[3].legend(loc="lower right")
fig.tight_layout()
plt.show()

# %% [markdown]
# **How to read it.** Only the band seen by both images is drawn. The grid covers the left
# image's footprint and only 22.0 % of its cells are seen by both images: hence `filled`
# 17.9 %, the share of the whole grid with a height; read it against the overlap, of which
# 81.1 % has a height. The **hillshade** (light from the north-west, heights doubled) shows
# the DSM's shape: the terrain rising to the east, the ravines, the tree crowns as a grain; a
# smooth, blurred patch would be a surface the matcher interpolated, stripes or waves across
# the whole DSM an orientation problem (jitter). The **holes** (red) are cells without a
# height, inside a few cells in the shadows of the trees, and above all a **ring along the
# edges of the overlap**, drawn in the last panel: of the overlap's cells within 1, 2 and 3 m
# of its edge, 0 %, 1 % and 2 % have a height; the share then rises (14 % at 4 m, 92 % at
# 10 m) to 100 % beyond 15 m, more slowly along the southern edge, where the red band is
# widest. The first 3 m are 9.6 % of the overlap and hold 51 % of its holes. They are empty
# all around on purpose: a height there would come from a matching window (SGM's
# block, and the correlation window that refines it and gives `height_sigma`: about 6 px, 3 m,
# on each side of the pixel) that reaches past one image's data; the matcher then takes the
# edge of the data for texture and matches it, and such heights come out metres wrong, with
# a sigma that does not say so. jaxgeo drops every disparity whose window meets no data: here
# 0.23 % of the 1708 cells within 3 cells of the DSM's edges lie more than 5 m from the
# median of their 9 x 9 neighbours, as rare as inside (0.12 %). A hole is not an error: holes
# up to a few metres across are interpolated (the `filled` band, cyan: 0.2 % of the heights);
# larger ones, the ring among them, stay NaN, for the next command to fill from another DEM
# (`--dem-fill`), never silently. The **height_sigma** map is each cell's standard deviation:
# the matching's (low on texture, high on shadows and steep edges, hence the bright streaks
# along the ravines) plus the orientation's, the same everywhere. Its median is 0.45 m,
# against 1.47 m for the DSM of the delivered models with their a priori orientation error:
# the adjustment's posterior pointing is what makes the heights worth half a metre. A cell
# with a large sigma is to be used with care, even though it has a height.
#
# An independent check of the DSM: the CARS triangulation that shareloc's tests take as a
# reference (points of this pair triangulated by CARS, with the delivered models, from a
# disparity map of its own: `triangulation/triangulation1_ref.npz`), compared with the DSM
# cell under each point.

# %%
ref = np.load(VENTOUX / "triangulation/triangulation1_ref.npz")
ok = ref["corr_msk"].ravel() > 0
ref_e, ref_n = to_utm.transform(ref["lon"].ravel()[ok], ref["lat"].ravel()[ok])
cars = {}
for kind, rep in dsms.items():
    with rasterio.open(rep.path) as f:
        h = f.read(1)
        cr = ~f.transform * (np.asarray(ref_e), np.asarray(ref_n))  # column, row (float)
        c, r = (np.floor(v).astype(int) for v in cr)
    inside = (r >= 0) & (r < h.shape[0]) & (c >= 0) & (c < h.shape[1])
    dh = h[r[inside], c[inside]] - ref["h"].ravel()[ok][inside]
    dh = dh[np.isfinite(dh)]
    cars[kind] = dh_stats(dh)
    print(f"DSM ({kind} models) - CARS: {cars[kind].cells} points, median "
          f"{cars[kind].median_m:+.2f} m, NMAD {cars[kind].nmad_m:.2f} m")  # fmt: skip
key_numbers["cars"] = {k: {"cells": s.cells, "median_m": num(s.median_m), "nmad_m": num(s.nmad_m)}
                       for k, s in cars.items()}  # fmt: skip

# %% [markdown]
# With the delivered models, the DSM agrees with CARS to +0.06 m (median) and 0.35 m (NMAD)
# over 13 069 points: the same models and the same pair, matched and triangulated by two
# independent programs, within a third of a metre, tree crowns included. The DSM of the
# adjusted models sits 3.94 m lower with the same NMAD: the adjustment moved the heights, not
# their shape. That is the SRTM tie heights at work: the relative shift along the epipolar
# direction, which the ties cannot see, was set so that the ties' heights agree with SRTM's
# (next section). Without GCPs, the block's absolute height is the DEM's.

# %% [markdown]
# ## 6. Co-registration onto SRTM: `coregister` (`jaxgeo coregister`)
#
# Nuth and Kääb's method: the horizontal shift from the relation between the height
# differences and the terrain's aspect and slope, iterated, then the vertical offset. SRTM is
# orthometric: the reference is given as `read_dem(srtm, geoid=...)` (`--geoid egm96`), its
# heights made ellipsoidal on the DSM's grid. First the full fit, as `jaxgeo coregister` runs
# by default, through the library and through the command.

# %%
srtm = VENTOUX / "dem/N44E005_srtm90.tif"
gtx = VENTOUX / "dem/egm96_15_crop_lon3-8_lat42-47.gtx"
try:  # the full fit (horizontal and vertical), as `jaxgeo coregister` runs by default
    coregister(WORK / "dsm_adjusted.tif", dem, WORK / "dsm_on_srtm.tif")
except CoregistrationError as err:
    refusal = str(err).replace(f"{WORK}/", "").replace(f"{srtm.parent}/", "")  # short names
    print(f"CoregistrationError: {refusal}")
else:
    raise AssertionError("the horizontal fit onto SRTM was not refused")
# what a user of the command sees: the same message, naming the option, exit status 2
for path in (srtm, gtx):  # beside the DSM: the command line and its message read short
    shutil.copy(path, WORK)
command = ["coregister", "dsm_adjusted.tif", srtm.name, "--geoid", gtx.name,
           "-o", "dsm_on_srtm.tif"]  # fmt: skip
cli = subprocess.run([sys.executable, "-c", "import sys; from jaxgeo.cli import main; "
                      "sys.exit(main(sys.argv[1:]))", *command],
                     capture_output=True, text=True, cwd=WORK,
                     env={**os.environ, "PYTHONPATH": str(REAL.parents[2])})  # fmt: skip
print(f"\n$ jaxgeo {' '.join(command)}\n{cli.stderr.strip()}\n(exit status {cli.returncode})")
lon_c, lat_c = pyproj.Transformer.from_crs("EPSG:32631", "EPSG:4326", always_xy=True).transform(
    east[has], north[has])  # fmt: skip
posts = (np.ptp(lon_c) * 1200, np.ptp(lat_c) * 1200)  # SRTM 3": 1200 posts per degree
spacing_m = (np.radians(1 / 1200) * 6_378_137 * np.cos(np.radians(np.mean(lat_c))),
             np.radians(1 / 1200) * 6_378_137)  # fmt: skip
print(f"\nthe DSM's heights span {posts[0]:.1f} x {posts[1]:.1f} SRTM posts (lon x lat), "
      f"{spacing_m[0]:.0f} m x {spacing_m[1]:.0f} m apart")  # fmt: skip
key_numbers["coregister_refused"] = {
    "exit": cli.returncode,
    "names_option": "--vertical-only" in cli.stderr,
    "posts": num(posts),
    "post_spacing_m": num(spacing_m),
}

# %% [markdown]
# **Refused, and rightly.** The DSM's heights span about three SRTM posts east-west and one
# north-south (3.1 x 0.9): SRTM knows this terrain as a handful of heights 66 m x 93 m apart,
# bilinearly interpolated, while the DSM sees it at 1 m. The difference is then the terrain
# itself (the ravine and the ridge that SRTM does not have), not a shift: the aspect-and-slope
# fit would have nothing stable to find (its increments swing by tens of metres from one
# iteration to the next, and it stops anywhere). So `coregister` refuses, before any fit, a
# DSM whose heights span fewer than 10 of the reference's cells in either direction
# (`NuthKaab(min_ref_cells=10)`): a `CoregistrationError` that names both files, the spans and
# what to do; the command prints it as one line, naming `--vertical-only`, and exits with
# status 2, writing nothing. To co-register horizontally, use a DSM many reference cells
# across (a whole scene against SRTM or the 30 m Copernicus DEM), or a reference of the DSM's
# resolution (below: the delivered models' DSM).
#
# What SRTM can give here is the vertical offset alone: `NuthKaab(vertical_only=True)`
# (`jaxgeo coregister dsm.tif N44E005_srtm90.tif --geoid egm96 --vertical-only -o
# dsm_on_srtm.tif --diff dh.tif`), `dz` the median of `DSM - SRTM` over the inliers.

# %%
vertical = NuthKaab(vertical_only=True)
onto_srtm = coregister(WORK / "dsm_adjusted.tif", dem, WORK / "dsm_on_srtm.tif",
                       diff=WORK / "dh_srtm.tif", settings=vertical)  # fmt: skip
srtm_dh = {}
srtm_cells = dem(np.stack(pyproj.Transformer.from_crs("EPSG:32631", "EPSG:4326", always_xy=True)
                          .transform(east, north), -1))  # fmt: skip
srtm_dh["before"] = height - srtm_cells  # SRTM (ellipsoidal) on the DSM's cells
with rasterio.open(WORK / "dh_srtm.tif") as f:
    srtm_dh["after"] = f.read(1)
dx, dy, dz = onto_srtm.shift_m
print(f"shift added to the DSM: dx {dx:+.2f} m, dy {dy:+.2f} m, dz {dz:+.2f} m "
      f"(vertical only), converged: {onto_srtm.converged}")  # fmt: skip
for kind, s in (("before", onto_srtm.diff.before), ("after", onto_srtm.diff.after)):
    print(f"DSM - SRTM {kind:6s}: {s.cells} cells, median {s.median_m:+.2f} m, "
          f"NMAD {s.nmad_m:.2f} m, LE90 {s.le90_m:.2f} m")  # fmt: skip
mine = dh_stats(srtm_dh["before"][np.isfinite(srtm_dh["before"])])
assert abs(mine.median_m - onto_srtm.diff.before.median_m) < 0.2, (mine, onto_srtm.diff.before)
delivered_on_srtm = coregister(WORK / "dsm_delivered.tif", dem, settings=vertical)
print(f"the DSM of the delivered models, vertical only onto SRTM: dz "
      f"{delivered_on_srtm.shift_m[2]:+.2f} m")  # fmt: skip
key_numbers["coregister_srtm"] = {
    "converged": bool(onto_srtm.converged),
    "shift_m": num(onto_srtm.shift_m),
    "before": {"median_m": num(onto_srtm.diff.before.median_m),
               "nmad_m": num(onto_srtm.diff.before.nmad_m), "cells": onto_srtm.diff.before.cells},
    "after": {"median_m": num(onto_srtm.diff.after.median_m),
              "nmad_m": num(onto_srtm.diff.after.nmad_m), "cells": onto_srtm.diff.after.cells},
    "delivered_dz_m": num(delivered_on_srtm.shift_m[2]),
}  # fmt: skip

# %% [markdown]
# The vertical offset alone: `dz` -0.12 m, the DSM of the adjusted models sits +0.12 m above
# SRTM (median over the 14 548 cells both have; -0.01 m after). That is not a finding about
# the DSM: it is the adjustment's datum. Without GCPs, the tie heights taken from SRTM set the
# block's height (section 3), so the adjusted DSM lies on SRTM by construction, and its `dz`
# says that the datum came through (the geoid applied, no metres lost); the DSM of the
# delivered models, which knows nothing of SRTM, needs -3.99 m, the height the adjustment
# took out (3.94 m against CARS). Before and after are over the same cells, and the NMAD,
# 10.51 m both times, is SRTM's resolution (the terrain between its posts), not the DSM's
# error: a constant does not change it. Read `dz` to SRTM's own vertical accuracy, metres,
# not to the centimetre.

# %%
onto_delivered = coregister(WORK / "dsm_adjusted.tif", WORK / "dsm_delivered.tif",
                            WORK / "dsm_on_delivered.tif",
                            diff=WORK / "dh_delivered.tif")  # fmt: skip
with rasterio.open(WORK / "dsm_delivered.tif") as f:
    assert f.transform == dsm_transform and f.shape == dsm_shape  # one grid (like=)
    delivered_dh = {"before": height - f.read(1)}
with rasterio.open(WORK / "dh_delivered.tif") as f:
    delivered_dh["after"] = f.read(1)
dx, dy, dz = onto_delivered.shift_m
print(f"shift added to the adjusted DSM: dx {dx:+.2f} m, dy {dy:+.2f} m, dz {dz:+.2f} m; "
      f"{onto_delivered.iterations} iterations, converged: {onto_delivered.converged}")  # fmt: skip
for kind, s in (("before", onto_delivered.diff.before), ("after", onto_delivered.diff.after)):
    print(f"DSM adjusted - delivered {kind:6s}: {s.cells} cells, median {s.median_m:+.2f} m, "
          f"NMAD {s.nmad_m:.2f} m, LE90 {s.le90_m:.2f} m")  # fmt: skip
key_numbers["coregister_delivered"] = {
    "converged": bool(onto_delivered.converged),
    "iterations": onto_delivered.iterations,
    "shift_m": num(onto_delivered.shift_m),
    "before": {"median_m": num(onto_delivered.diff.before.median_m),
               "nmad_m": num(onto_delivered.diff.before.nmad_m)},
    "after": {"median_m": num(onto_delivered.diff.after.median_m),
              "nmad_m": num(onto_delivered.diff.after.nmad_m)},
}  # fmt: skip

# %%
fig, axes = plt.subplots(2, 3, figsize=(17, 7.5), width_ratios=[1, 1, 0.8], dpi=80)
rows_drawn = (("DSM - SRTM (vertical only)", srtm_dh, 25.0),
              ("adjusted - delivered DSM", delivered_dh, 8.0))  # fmt: skip
for row, (title, dh, lim) in enumerate(rows_drawn):
    for col, kind in enumerate(("before", "after")):
        ax = axes[row, col]
        im = ax.imshow(dh[kind][window], cmap="RdBu_r", vmin=-lim, vmax=lim, extent=dsm_extent)
        s = dh_stats(dh[kind][np.isfinite(dh[kind])])
        ax.set(title=f"{title}, {kind}\nmedian {s.median_m:+.2f} m, NMAD {s.nmad_m:.2f} m",
               ylabel="north (m)")  # fmt: skip
        ax.ticklabel_format(useOffset=False, style="plain")
        ax.tick_params(axis="x", labelrotation=20)
        fig.colorbar(im, ax=ax, label="dh (m)", extend="both", shrink=0.7)
    ax = axes[row, 2]
    bins = np.linspace(-lim, lim, 82)  # 81 bins, one centred on zero
    for kind, colour in (("before", "tab:red"), ("after", "tab:blue")):
        v = dh[kind][np.isfinite(dh[kind])]
        ax.hist(np.clip(v, -lim, lim), bins=bins, histtype="step", lw=1.5, color=colour,
                label=f"{kind} ({len(v)} cells)")  # fmt: skip
    ax.set(xlabel="dh (m), clipped", ylabel="cells", title=f"{title}: histogram")
    ax.legend(fontsize=8)
fig.tight_layout()
plt.show()

# %% [markdown]
# **How to read it.** A difference map after a good co-registration is centred on zero
# (white) with no pattern that follows the terrain: what is left is change (here none),
# vegetation and noise. A pattern that follows the slopes (red on one side of each ridge,
# blue on the other) is a horizontal shift left; a ramp across the whole map, a tilt; a
# uniform colour, a vertical offset.
#
# Top row, against SRTM: before, blue in the ravine to the west and red on the ridge to the
# east: SRTM's smoothed terrain, not a shift, and a histogram with two humps; after the
# vertical-only co-registration the same picture, moved by 0.12 m: a vertical offset cannot
# take out what SRTM does not resolve, and nothing here would. Bottom row, against the
# delivered models' DSM (same images, same grid): before, a uniform blue, the 4.03 m by which
# the adjustment lowered the heights (median; NMAD 0.09 m); after, white, the histogram one
# narrow peak at zero (median +0.00 m, NMAD 0.09 m). The shift found, (+0.04, -0.07, +4.04) m
# in 9 iterations, is the adjustment's move undone: a height change, and almost no
# horizontal move, because the two images moved by 1.4 m in opposite directions (section 3),
# which changes where their rays meet in height, not in plan.

# %% [markdown]
# ## What to expect, in one table
#
# | step | number | here |
# |---|---|---|
# | match | ties kept of candidates | 689 of 907 |
# | match | offset across the epipolar curves (the RPCs' relative bias) | -4.75 px |
# | adjust | tie residual RMS (column, row), before: left, right | (2.32, 0.62), (2.33, 0.64) px |
# | adjust | after: left, right | (0.17, 0.05), (0.18, 0.05) px |
# | adjust | s0 (a priori 0.5 px) | 0.61 |
# | adjust | relative bias shift right - left | (+3.89, +3.98) px, 2.8 m |
# | adjust | each image's shift on the ground | 1.4 m, in opposite directions |
# | ortho | pixels with data (the rest: outside the crop) | 90.5 % of 533 x 514 px of 0.5 m |
# | dsm | cells with a height: of the grid / of the overlap | 17.9 % / 81.1 % |
# | dsm | the empty ring: overlap cells within 3 m of its edge with a height | 0 %, 1 %, 2 % |
# | dsm | cells > 5 m off their neighbours: within 3 cells of the edges / inside | 0.23 % / 0.12 % |
# | dsm | median height_sigma, adjusted / delivered models | 0.45 m / 1.47 m |
# | dsm | against CARS (delivered models): median, NMAD | +0.06 m, 0.35 m |
# | coregister onto SRTM, full fit | 3.1 x 0.9 SRTM posts: refused (exit 2) | `--vertical-only` |
# | coregister onto SRTM, vertical only | dz: adjusted / delivered DSM | -0.12 m / -3.99 m |
# | coregister onto SRTM, vertical only | NMAD (SRTM's resolution) | 10.51 m |
# | coregister onto the delivered DSM | shift (E, N, up) | (+0.04, -0.07, +4.04) m |
# | coregister onto the delivered DSM | NMAD before / after | 0.09 / 0.09 m |
#
# The key numbers as one JSON line: `tests/notebooks/test_notebook_06.py` runs this notebook
# and checks the statements of the text against them.

# %%
shutil.rmtree(WORK)
print("NOTEBOOK_RESULTS", json.dumps(key_numbers, sort_keys=True))
print(
    f"notebook run time {time.perf_counter() - T0:.0f} s wall, "
    f"{time.process_time() - C0:.0f} s CPU (jaxgeo {jaxgeo.__version__})"
)

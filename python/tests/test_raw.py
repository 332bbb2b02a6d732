"""Camera RAW (issue 33): a DNG written by an independent tool (PyPI's ``pidng``, from a Bayer
mosaic made here) reads as the linear values LibRaw (``rawpy``) reads from it, within 1 in the
16-bit scale, and a capture of such DNGs reconstructs like the 16-bit render it was made from.

``photostereo`` reads a Bayer DNG at half size: each 2x2 block is one pixel with its red, the
mean of its two greens and its blue, black level subtracted, white level at 1, no white balance.
The reference below builds exactly that from LibRaw's visible raw samples, its per-site colours
and black levels."""

import subprocess

import numpy as np
import pytest

import photostereo as ps

rawpy = pytest.importorskip("rawpy", reason="test.sh installs rawpy (LibRaw)")
pidng_core = pytest.importorskip("pidng.core", reason="test.sh installs pidng")
from pidng.defs import (  # noqa: E402
    CalibrationIlluminant,
    CFAPattern,
    DNGVersion,
    Orientation,
    PhotometricInterpretation,
    PreviewColorSpace,
)

PATTERNS = {"RGGB": CFAPattern.RGGB, "GRBG": CFAPattern.GRBG, "BGGR": CFAPattern.BGGR,
            "GBRG": CFAPattern.GBRG}


def write_dng(path, mosaic, pattern, bits, black, neutral=(0.5, 1.0, 0.6)):
    """A DNG written by pidng: one uncompressed CFA tile, with a white balance (AsShotNeutral)
    that photostereo must not apply."""
    h, w = mosaic.shape
    t = pidng_core.DNGTags()
    t.set(pidng_core.Tag.ImageWidth, w)
    t.set(pidng_core.Tag.ImageLength, h)
    t.set(pidng_core.Tag.TileWidth, w)
    t.set(pidng_core.Tag.TileLength, h)
    t.set(pidng_core.Tag.Orientation, Orientation.Horizontal)
    t.set(pidng_core.Tag.PhotometricInterpretation, PhotometricInterpretation.Color_Filter_Array)
    t.set(pidng_core.Tag.SamplesPerPixel, 1)
    t.set(pidng_core.Tag.BitsPerSample, bits)
    t.set(pidng_core.Tag.CFARepeatPatternDim, [2, 2])
    t.set(pidng_core.Tag.CFAPattern, PATTERNS[pattern])
    t.set(pidng_core.Tag.BlackLevel, black)
    t.set(pidng_core.Tag.WhiteLevel, (1 << bits) - 1)
    t.set(pidng_core.Tag.ColorMatrix1, [[32404, 10000], [-15371, 10000], [-4985, 10000],
                                        [-9692, 10000], [18760, 10000], [415, 10000],
                                        [556, 10000], [-2040, 10000], [10572, 10000]])
    t.set(pidng_core.Tag.CalibrationIlluminant1, CalibrationIlluminant.D65)
    t.set(pidng_core.Tag.AsShotNeutral, [[int(v * 1000), 1000] for v in neutral])
    t.set(pidng_core.Tag.Make, "Photostereo")
    t.set(pidng_core.Tag.Model, "Test Bayer")
    t.set(pidng_core.Tag.DNGVersion, DNGVersion.V1_4)
    t.set(pidng_core.Tag.DNGBackwardVersion, DNGVersion.V1_2)
    t.set(pidng_core.Tag.PreviewColorSpace, PreviewColorSpace.sRGB)
    r = pidng_core.RAW2DNG()
    r.options(t, path="", compress=False)
    r.convert(mosaic, filename=str(path.with_suffix("")))
    return path


def mosaic_of(rgb, pattern, bits, black):
    """The Bayer samples of an (H, W, 3) linear image in [0, 1] at twice its size."""
    h, w, _ = rgb.shape
    white = (1 << bits) - 1
    out = np.zeros((2 * h, 2 * w), np.uint16)
    # The pattern's name spells its 2x2 sites in row order.
    for site, colour in enumerate(pattern):
        c = "RGB".index(colour)
        dy, dx = divmod(site, 2)
        out[dy::2, dx::2] = np.round(black + np.clip(rgb[:, :, c], 0, 1) * (white - black))
    return out


def libraw_half(path):
    """LibRaw's reading, made half size as photostereo documents it: (raw - black) /
    (white - black) per site, the two greens averaged."""
    with rawpy.imread(str(path)) as d:
        raw = d.raw_image_visible.astype(np.float64)
        colours = d.raw_colors_visible
        black = np.array(d.black_level_per_channel, np.float64)[colours]
        white = float(d.white_level)
        lin = (raw - black) / (white - black)
        colour_names = d.color_desc.decode()
    h, w = raw.shape[0] // 2, raw.shape[1] // 2
    out = np.zeros((h, w, 3))
    for dy in range(2):
        for dx in range(2):
            name = colour_names[colours[dy, dx]]
            c = "RGB".index(name)
            weight = 0.5 if name == "G" else 1.0
            out[:, :, c] += weight * lin[dy::2, dx::2][:h, :w]
    return np.clip(out, 0.0, 1.0)


@pytest.mark.parametrize("pattern", sorted(PATTERNS))
# (pidng 4.0.9 packs 14-bit samples only for some widths: 12 and 16 bits here.)
@pytest.mark.parametrize("bits,black", [(12, 256), (16, 1024)])
def test_dng_reads_as_libraw_reads_it(tmp_path, pattern, bits, black):
    rng = np.random.default_rng(bits)
    rgb = rng.uniform(0.0, 1.0, (23, 31, 3))
    path = write_dng(tmp_path / "t.dng", mosaic_of(rgb, pattern, bits, black), pattern, bits,
                     black)
    ours = ps.read_image(path).astype(np.float64)
    reference = libraw_half(path)
    assert ours.shape == reference.shape == (23, 31, 3)
    # Within 1 in the 16-bit scale of the two readings.
    gap = np.abs(ours - reference).max() * 65535
    assert gap <= 1.0, gap
    # And the values the mosaic was made from, within one sensor step.
    step = 1.0 / ((1 << bits) - 1 - black)
    assert np.abs(ours - rgb).max() <= step * 1.01


def test_a_dng_capture_reconstructs_like_its_16bit_render(cli, tmp_path):
    png = tmp_path / "png"
    subprocess.run([cli, "synth", "sphere", "--rig", "dome-24", "--brdf", "lambert", "--size",
                    "64", "-q", "-o", str(png)], check=True)
    dng = tmp_path / "dng"
    dng.mkdir()
    for f in ["light_directions.txt", "light_intensities.txt", "mask.png"]:
        if (png / f).exists():
            (dng / f).write_bytes((png / f).read_bytes())
    images = sorted(p for p in png.glob("*.png") if p.name != "mask.png")
    for k, p in enumerate(images):
        rgb = ps.read_image(p)
        write_dng(dng / f"{k + 1:03}.dng", mosaic_of(rgb, "RGGB", 12, 256), "RGGB", 12, 256)
    truth = png / "gt" / "normal.npy"
    ref = ps.run(png, tmp_path / "r-png", gt=truth, method="l2", integrate=False)
    raw = ps.run(dng, tmp_path / "r-dng", gt=truth, method="l2", integrate=False)
    assert raw["input"]["lights"] == len(images)
    # 12 bits against 16: the quantisation is far under the render's noise.
    assert abs(raw["error"]["mean_deg"] - ref["error"]["mean_deg"]) < 0.05, (
        raw["error"]["mean_deg"], ref["error"]["mean_deg"])
    first = raw["photometry"]["images"][0]
    assert first["response"] == "linear"
    assert "white balance none" in first["decoder"]

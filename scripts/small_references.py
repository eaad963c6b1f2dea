#!/usr/bin/env python3
"""Box-downsamples the Tungsten reference EXRs of ../shared/scenes-public by an integer
factor into tests/public-scenes/ (float32 RGB, ZIP-compressed), so the import tests run
from a clone without the shared folder. The tests box-average a reference down to their
render's size; averaging 1024² → 256² here and 256² → 64² there is the same average as
1024² → 64² in one step (each factor divides), so the tests' numbers do not change beyond
rounding to float32 (the originals are half floats).

usage: python3 scripts/small_references.py     (needs `pip install mitsuba numpy`: its
Bitmap reads and writes OpenEXR)
"""
from pathlib import Path

import mitsuba as mi
import numpy as np

mi.set_variant("scalar_rgb")
ROOT = Path(__file__).resolve().parent.parent
PUBLIC = ROOT.parent / "shared/scenes-public"
OUT = ROOT / "tests/public-scenes"
# folder: (width, height) of the small reference; each divides the original's size.
SIZES = {
    "cornell-box-bitterli": (256, 256),
    "veach-mis-bitterli": (256, 144),
    "veach-bidir-bitterli": (256, 256),
}

for folder, (w, h) in SIZES.items():
    src = np.array(mi.Bitmap(str(PUBLIC / folder / "TungstenRender.exr")), dtype=np.float64)[..., :3]
    H, W = src.shape[:2]
    assert W % w == 0 and H % h == 0, (folder, W, H)
    small = src.reshape(h, H // h, w, W // w, 3).mean(axis=(1, 3)).astype(np.float32)
    out = OUT / folder / f"TungstenRender-{w}x{h}.exr"
    out.parent.mkdir(parents=True, exist_ok=True)
    mi.Bitmap(small, mi.Bitmap.PixelFormat.RGB).write(str(out))
    print(f"{out.relative_to(ROOT)}: {W}x{H} -> {w}x{h}, mean {small.reshape(-1, 3).mean(axis=0)}, "
          f"{out.stat().st_size} bytes")

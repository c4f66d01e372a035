#!/usr/bin/env python3
"""Writes src/bench/font.rs: printable ASCII as 7x13 one-bit glyphs, rasterised from
DejaVu Sans Mono (Bitstream Vera licence), for labelling the benchmark plots without a
font library. Needs Pillow and the DejaVu fonts; run from the repository root."""
from PIL import Image, ImageDraw, ImageFont

W, H = 7, 13
font = ImageFont.truetype("/usr/share/fonts/truetype/dejavu/DejaVuSansMono.ttf", 11)
rows = []
for c in range(32, 127):
    img = Image.new("L", (W, H), 0)
    ImageDraw.Draw(img).text((0, 0), chr(c), font=font, fill=255)
    bits = []
    for y in range(H):
        v = 0
        for x in range(W):
            if img.getpixel((x, y)) >= 110:
                v |= 1 << x
        bits.append(v)
    rows.append(bits)
with open("src/bench/font.rs", "w") as f:
    f.write("//! Printable ASCII as 7×13 one-bit glyphs (bit x of row y), rasterised from DejaVu Sans\n")
    f.write("//! Mono by `scripts/make-font.py`; for labelling benchmark plots. Do not edit.\n\n")
    f.write(f"/// Glyph width in pixels.\npub const WIDTH: u32 = {W};\n")
    f.write(f"/// Glyph height in pixels.\npub const HEIGHT: u32 = {H};\n\n")
    f.write("/// Rows of the glyphs of ' ' to '~'.\n")
    f.write(f"pub const GLYPHS: [[u8; {H}]; 95] = [\n")
    for c, bits in zip(range(32, 127), rows):
        f.write("    [" + ", ".join(str(b) for b in bits) + f"], // {chr(c)!r}\n")
    f.write("];\n")

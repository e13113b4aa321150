"""The scale values of a Scheffé analysis as a bar chart (SVG), like the paper's: one bar per
configuration from zero, the yardstick drawn to scale, the letter groups under the names."""
from __future__ import annotations

import math
from xml.sax.saxutils import escape

from studies.scheffe import ScheffeResult


def scale_chart_svg(res: ScheffeResult, *, level: float = 0.05, title: str = "Scale values") -> str:
    """An SVG document (text) of ``res``'s scale values, items in input order."""
    w, h, left, right, top, bottom = 640, 360, 60, 20, 40, 70
    vals = [float(v) for v in res.scale]
    yard = res.yardstick.get(level, math.nan)
    yard = yard if math.isfinite(yard) else None           # undefined (an error term of 0): not drawn
    y_abs = max(max(abs(v) for v in vals), yard or 0.0) * 1.15 or 1.0
    plot_h = h - top - bottom
    zero = top + plot_h / 2
    scale = (plot_h / 2) / y_abs
    step = (w - left - right) / len(vals)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" '
           f'font-size="12">', f'<rect width="{w}" height="{h}" fill="white"/>',
           f'<text x="{w / 2}" y="20" text-anchor="middle" font-size="14">{escape(title)}</text>',
           f'<line x1="{left}" y1="{zero}" x2="{w - right}" y2="{zero}" stroke="black"/>',
           f'<line x1="{left}" y1="{top}" x2="{left}" y2="{h - bottom}" stroke="black"/>']
    for tick in (-y_abs, -y_abs / 2, 0.0, y_abs / 2, y_abs):
        y = zero - tick * scale
        out.append(f'<text x="{left - 6}" y="{y + 4}" text-anchor="end">{tick:.2f}</text>')
    letters = res.letters.get(level, ("",) * len(vals))
    for k, (name, v, letter) in enumerate(zip(res.items, vals, letters)):
        x = left + k * step + step * 0.2
        y0, y1 = sorted((zero, zero - v * scale))
        out.append(f'<rect x="{x:.1f}" y="{y0:.1f}" width="{step * 0.6:.1f}" height="{y1 - y0:.1f}" fill="#4a78b0"/>')
        out.append(f'<text x="{x + step * 0.3:.1f}" y="{h - bottom + 18}" text-anchor="middle">{escape(name)}</text>')
        out.append(f'<text x="{x + step * 0.3:.1f}" y="{h - bottom + 34}" text-anchor="middle" '
                   f'fill="#555">{escape(letter)}</text>')
    if yard is not None:
        y = yard * scale
        x = w - right - 12
        out.append(f'<line x1="{x}" y1="{zero - y / 2:.1f}" x2="{x}" y2="{zero + y / 2:.1f}" stroke="#c03" '
                   f'stroke-width="3"/>')
        out.append(f'<text x="{x - 6}" y="{zero - y / 2 - 6:.1f}" text-anchor="end" fill="#c03">'
                   f'Y(p&lt;{level:g}) = {yard:.3f}</text>')
    out.append(f'<text x="{left}" y="{h - 8}" fill="#555">scale value (positive: preferred); configurations '
               f'sharing a letter do not differ at p &lt; {level:g}</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"

"""Calibration plots, drawn with OpenCV as BGR uint8 images: line charts (the sensitivity
analysis's Figures 7-9), the image circle's overlay (``acq calibrate fisheye``) and the
extrinsic calibration's residuals (``acq calibrate extrinsic``)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from acq.calib.board_pose import BoardPose
from acq.calib.circle_fit import ImageCircle
from acq.calib.extrinsic import ExtrinsicResult, point_residuals
from acq.calib.image_circle import CircleResult
from acq.calib.sensitivity import PARAMS, Analysis, bin_by_theta, format_sigma, third_order_px
from acq.camera.camera_models import KannalaBrandt
from acq.provenance import write_image

__all__ = [
    "PALETTE",
    "draw_legend",
    "draw_overlay",
    "line_plot",
    "residual_plot",
    "sensitivity_figure",
    "third_order_figure",
]

# --- primitives --------------------------------------------------------------------------

PALETTE = [
    (178, 114, 0),
    (0, 94, 213),
    (115, 158, 0),
    (167, 121, 204),
    (0, 159, 230),
    (233, 180, 86),
    (66, 228, 240),
    (0, 0, 0),
    (128, 128, 128),
    (40, 40, 160),
    (160, 40, 40),
    (40, 120, 40),
]
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _nice_ticks(lo: float, hi: float, n: int = 6) -> np.ndarray:
    if not hi > lo:
        hi = lo + 1.0
    raw = (hi - lo) / n
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first, last = math.floor(lo / step + 1e-9), math.ceil(hi / step - 1e-9)
    ticks: np.ndarray = np.arange(first, max(last, first + 1) + 1) * step
    return ticks


def _text(
    img: np.ndarray, s: str, xy: tuple[int, int], scale: float = 0.5, anchor: str = "l"
) -> None:
    (w, h), _ = cv2.getTextSize(s, _FONT, scale, 1)
    x, y = xy
    if anchor == "c":
        x -= w // 2
    elif anchor == "r":
        x -= w
    cv2.putText(img, s, (x, y + h // 2), _FONT, scale, (0, 0, 0), 1, cv2.LINE_AA)


def draw_legend(
    img: np.ndarray,
    entries: Sequence[tuple[tuple[int, int, int] | None, str]],
    corner: str = "bl",
    scale: float = 0.45,
) -> tuple[int, int, int, int]:
    """Draw a legend into ``img`` (BGR uint8, in place): one line per entry, a square of
    its colour (BGR; None: a line of text only) and its label, white on a darkened box
    in the corner ``corner`` ("tl", "tr", "bl", "br"). The box (x0, y0, x1, y1), px."""
    pad, sw = 6, 10
    sizes = [cv2.getTextSize(label, _FONT, scale, 1)[0] for _, label in entries]
    line_h = max(h for _, h in sizes) + 8
    width = 2 * pad + sw + 6 + max(w for w, _ in sizes)
    height = 2 * pad + line_h * len(entries) - 8
    h_img, w_img = img.shape[:2]
    x0 = 4 if corner[1] == "l" else w_img - width - 4
    y0 = 4 if corner[0] == "t" else h_img - height - 4
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x0 + width, w_img), min(y0 + height, h_img)
    img[y0:y1, x0:x1] = (img[y0:y1, x0:x1] * 0.3).astype(np.uint8)
    for k, ((colour, label), (_, th)) in enumerate(zip(entries, sizes, strict=True)):
        top = y0 + pad + k * line_h
        x = x0 + pad
        if colour is not None:
            cv2.rectangle(img, (x, top), (x + sw - 1, top + sw - 1), colour, -1)
            x += sw + 6
        cv2.putText(img, label, (x, top + (sw + th) // 2), _FONT, scale, (255, 255, 255), 1,
                    cv2.LINE_AA)  # fmt: skip
    return x0, y0, x1, y1


def line_plot(
    series: Sequence[tuple[str, np.ndarray, np.ndarray]],
    title: str,
    xlabel: str,
    ylabel: str,
    size: tuple[int, int] = (960, 600),
    log_y: bool = False,
    hlines: Sequence[float] = (),
) -> np.ndarray:
    """(H, W, 3) uint8 BGR line chart of ``(label, x, y)`` series with axes, ticks, grid,
    labels and a legend on the right; log10 y axis with ``log_y`` (y <= 0 dropped)."""
    W, H = size
    img = np.full((H, W, 3), 255, np.uint8)
    left, right, top, bottom = 90, 190, 45, 60
    x0, x1, y0, y1 = left, W - right, top, H - bottom
    xs = [np.asarray(x, float) for _, x, _ in series]
    ys = [np.asarray(y, float) for _, _, y in series]
    if log_y:
        ys = [np.where(y > 0, np.log10(np.where(y > 0, y, 1.0)), np.nan) for y in ys]
    allx = np.concatenate([x[np.isfinite(y)] for x, y in zip(xs, ys, strict=True)] + [np.zeros(0)])
    ally = np.concatenate([y[np.isfinite(y)] for y in ys] + [np.asarray(hlines, float)])
    xlo, xhi = (float(allx.min()), float(allx.max())) if allx.size else (0.0, 1.0)
    ylo, yhi = (float(ally.min()), float(ally.max())) if ally.size else (0.0, 1.0)
    if log_y:
        ylo, yhi = math.floor(ylo), math.ceil(yhi)
        yticks = np.arange(ylo, yhi + 1)
        if len(yticks) < 2:
            yticks = np.array([ylo, ylo + 1])
    else:
        ylo = min(ylo, 0.0)
        yticks = _nice_ticks(ylo, yhi * 1.05 if yhi > 0 else 1.0)
    xticks = _nice_ticks(min(xlo, 0.0), xhi)
    xlo, xhi = float(xticks[0]), float(xticks[-1])
    ylo, yhi = float(yticks[0]), float(yticks[-1])

    def px(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.stack(
            [x0 + (x - xlo) / (xhi - xlo) * (x1 - x0), y1 - (y - ylo) / (yhi - ylo) * (y1 - y0)],
            axis=-1,
        )

    for t in xticks:
        X = round(float(px(np.array(t), np.array(ylo))[0]))
        cv2.line(img, (X, y0), (X, y1), (225, 225, 225), 1)
        cv2.line(img, (X, y1), (X, y1 + 5), (0, 0, 0), 1)
        _text(img, f"{t:g}", (X, y1 + 16), 0.45, "c")
    for t in yticks:
        Y = round(float(px(np.array(xlo), np.array(t))[1]))
        cv2.line(img, (x0, Y), (x1, Y), (225, 225, 225), 1)
        cv2.line(img, (x0 - 5, Y), (x0, Y), (0, 0, 0), 1)
        _text(img, f"1e{int(t)}" if log_y else f"{t:g}", (x0 - 8, Y), 0.45, "r")
    for h in hlines:
        Y = round(float(px(np.array(xlo), np.array(h))[1]))
        for X in range(x0, x1, 12):
            cv2.line(img, (X, Y), (min(X + 6, x1), Y), (90, 90, 90), 1)
    cv2.rectangle(img, (x0, y0), (x1, y1), (0, 0, 0), 1)
    for k, (x, y) in enumerate(zip(xs, ys, strict=True)):
        colour = PALETTE[k % len(PALETTE)]
        ok = np.isfinite(x) & np.isfinite(y)
        pts = px(x, np.clip(y, ylo, yhi))
        # split at gaps (NaN) so no line jumps over them
        for seg in np.split(np.arange(len(x)), np.flatnonzero(~ok)):
            seg = seg[ok[seg]]
            if len(seg) > 1:
                poly = np.round(pts[seg]).astype(np.int32).reshape(-1, 1, 2)
                cv2.polylines(img, [poly], False, colour, 2, cv2.LINE_AA)
            elif len(seg) == 1:
                c = pts[seg[0]]
                cv2.circle(img, (int(c[0]), int(c[1])), 3, colour, -1, cv2.LINE_AA)
    for k, (label, _, _) in enumerate(series):
        Y = y0 + 12 + 22 * k
        cv2.line(img, (x1 + 15, Y), (x1 + 45, Y), PALETTE[k % len(PALETTE)], 3, cv2.LINE_AA)
        _text(img, label, (x1 + 52, Y), 0.5)
    _text(img, title, (W // 2, 20), 0.6, "c")
    _text(img, xlabel, ((x0 + x1) // 2, H - 18), 0.5, "c")
    (tw, th), _ = cv2.getTextSize(ylabel, _FONT, 0.5, 1)
    flat = np.full((th + 10, tw + 4, 3), 255, np.uint8)
    cv2.putText(flat, ylabel, (2, th + 3), _FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    lab = np.rot90(flat)  # counter-clockwise: reads bottom to top
    yy = max((y0 + y1) // 2 - lab.shape[0] // 2, 0)
    hh = min(lab.shape[0], H - yy)
    img[yy : yy + hh, 8 : 8 + lab.shape[1]] = lab[:hh]
    return img


# --- the image circle --------------------------------------------------------------------


_ESTIMATOR_COLOURS = {
    "barycentre": (0, 165, 255),
    "canny_fit": (255, 128, 0),
    "hough": (255, 0, 255),
    "subpixel": (0, 255, 0),
}


def _draw_curve(img: np.ndarray, c: ImageCircle, colour: tuple[int, int, int], thick: int) -> None:
    s = 16  # 4 fractional bits
    cv2.ellipse(
        img,
        (round(c.cx * s), round(c.cy * s)),
        (round(c.rx * s), round(c.ry * s)),
        0,
        0,
        360,
        colour,
        thick,
        cv2.LINE_AA,
        4,
    )
    x, y, d = round(c.cx * s), round(c.cy * s), 8 * s
    cv2.line(img, (x - d, y), (x + d, y), colour, thick, cv2.LINE_AA, 4)
    cv2.line(img, (x, y - d), (x, y + d), colour, thick, cv2.LINE_AA, 4)


def draw_overlay(image: np.ndarray, result: CircleResult, title: str = "") -> np.ndarray:
    """The image with every estimator's circle and centre, and the sub-pixel rim points
    (green kept, red rejected), plus a legend. (H,W,3) uint8 BGR."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    out = (img[:, :, :3] // 2 + 0).astype(np.uint8)
    pts = result.edges.points
    for (x, y), ok in zip(pts, result.edges.inlier, strict=True):
        cv2.circle(out, (round(x), round(y)), 1, (0, 200, 0) if ok else (0, 0, 255), -1)
    for name, est in result.estimates.items():
        _draw_curve(out, est.circle, _ESTIMATOR_COLOURS[name], 2 if name == "subpixel" else 1)
    c = result.circle
    lines = [title] if title else []
    lines.append(f"centre ({c.cx:.2f}, {c.cy:.2f}) r {c.radius:.2f} px")
    lines += [f"{k}" for k in result.estimates]
    y = 18
    for text in lines:
        colour = _ESTIMATOR_COLOURS.get(text, (255, 255, 255))
        cv2.putText(out, text, (8, y), _FONT, 0.5, colour, 1, cv2.LINE_AA)
        y += 18
    if result.truncated:
        msg = f"truncated ({', '.join(result.truncated)}): barycentre biased"
        cv2.putText(out, msg, (8, out.shape[0] - 10), _FONT, 0.5, (0, 200, 255), 1)
    return out


# --- the extrinsic calibration -----------------------------------------------------------


def residual_plot(
    result: ExtrinsicResult, poses: Sequence[BoardPose], path: str | Path
) -> np.ndarray:
    """Write a PNG (and return the BGR image): left, each pose's RMS residual (mm, dropped
    poses in red, the median and the outlier threshold as lines); right, the histogram of
    the kept poses' point residuals (mm) with a Gaussian of their RMS."""
    W, H, m = 1100, 420, 50
    img = np.full((H, W, 3), 255, np.uint8)
    black, grey, red, blue = (0, 0, 0), (170, 170, 170), (40, 40, 220), (200, 120, 40)
    res = point_residuals(poses, result.camera_to_laser)
    rms_mm = np.asarray(result.residuals_per_pose) * 1e3

    # left panel: per-pose bars
    x0, x1, y0, y1 = m, W // 2 - 20, m, H - m
    thr_mm = result.outlier_threshold_m * 1e3
    top = max(float(rms_mm.max()) if len(rms_mm) else 1.0, 1e-6)
    if math.isfinite(thr_mm):
        top = max(top, thr_mm)
    top *= 1.1

    def ly(v: float) -> int:
        return round(y1 - (y1 - y0) * v / top)

    cv2.rectangle(img, (x0, y0), (x1, y1), black, 1)
    bw = (x1 - x0) / max(len(rms_mm), 1)
    for i, v in enumerate(rms_mm):
        colour = red if i in result.outliers else blue
        a = int(x0 + i * bw + 0.15 * bw)
        b = int(x0 + (i + 1) * bw - 0.15 * bw)
        cv2.rectangle(img, (a, ly(float(v))), (max(b, a + 1), y1), colour, -1)
        if len(rms_mm) <= 40:
            cv2.putText(img, str(i), (a, y1 + 14), _FONT, 0.35, black, 1)
    med = float(np.median(rms_mm)) if len(rms_mm) else 0.0
    cv2.line(img, (x0, ly(med)), (x1, ly(med)), grey, 1)
    if math.isfinite(thr_mm):
        cv2.line(img, (x0, ly(thr_mm)), (x1, ly(thr_mm)), red, 1)
    cv2.putText(img, f"{top:.1f} mm", (x0 - 45, y0 + 4), _FONT, 0.35, black, 1)
    cv2.putText(img, "0", (x0 - 12, y1 + 4), _FONT, 0.35, black, 1)
    title = f"RMS residual per pose, mm (grey: median {med:.1f}, red: threshold {thr_mm:.1f})"
    cv2.putText(img, title, (x0, y0 - 15), _FONT, 0.45, black, 1)

    # right panel: histogram of kept point residuals
    kept = [r for i, r in enumerate(res) if i not in result.outliers]
    vals = np.concatenate(kept) * 1e3 if kept else np.zeros(1)
    x0, x1 = W // 2 + 40, W - m
    lim = max(float(np.percentile(np.abs(vals), 99.5)), 1e-6) * 1.2
    bins = np.linspace(-lim, lim, 41)
    hist, _ = np.histogram(np.clip(vals, -lim, lim), bins)
    hmax = max(int(hist.max()), 1)
    cv2.rectangle(img, (x0, y0), (x1, y1), black, 1)
    bwr = (x1 - x0) / len(hist)
    for i, c in enumerate(hist):
        a = int(x0 + i * bwr)
        b = int(x0 + (i + 1) * bwr) - 1
        cv2.rectangle(img, (a, int(y1 - (y1 - y0) * c / hmax / 1.1)), (b, y1), blue, -1)
    sd = float(np.sqrt(np.mean(vals**2)))
    if sd > 0:
        xs = np.linspace(-lim, lim, 200)
        pdf = len(vals) * (bins[1] - bins[0]) * np.exp(-0.5 * (xs / sd) ** 2)
        pdf /= sd * math.sqrt(2 * math.pi)
        pts = np.column_stack(
            [x0 + (xs + lim) / (2 * lim) * (x1 - x0), y1 - (y1 - y0) * pdf / hmax / 1.1]
        )
        cv2.polylines(img, [pts.astype(np.int32)], False, red, 1, cv2.LINE_AA)
    cv2.putText(img, f"{-lim:.1f}", (x0 - 10, y1 + 16), _FONT, 0.35, black, 1)
    cv2.putText(img, f"{lim:.1f} mm", (x1 - 30, y1 + 16), _FONT, 0.35, black, 1)
    title = f"point residuals, kept poses (n={len(vals)}, RMS {sd:.2f} mm)"
    cv2.putText(img, title, (x0, y0 - 15), _FONT, 0.45, black, 1)
    write_image(path, img)
    return img


# --- the sensitivity analysis (paper §4.1) -----------------------------------------------


def sensitivity_figure(a: Analysis, names: Sequence[str], what: str, bin_deg: float) -> np.ndarray:
    """Figures 7 and 8: eq. (7) median |s| and px per sigma of the parameters ``names``
    along theta (``bin_deg`` bins), two panels."""
    idx = [PARAMS.index(n) for n in names]
    c, _, med_s = bin_by_theta(a.theta, a.sens[:, idx], bin_deg)
    _, _, med_px = bin_by_theta(a.theta, a.shift[:, idx], bin_deg)
    top = line_plot(
        [(n, c, med_s[:, k]) for k, n in enumerate(names)],
        f"{what}: sensitivity, eq. (7), median |s| per {bin_deg:g} deg bin",
        "theta (deg from the optical axis)",
        "|s| (log)",
        log_y=True,
    )
    star = ["*" if a.sigma_source and a.sigma_source[i] == "default" else "" for i in idx]
    labels = [
        f"{n} ({format_sigma(a.sigma[i], i, a.params[i])}{m})"
        for n, i, m in zip(names, idx, star, strict=True)
    ]
    bottom = line_plot(
        [(lab, c, med_px[:, k]) for k, lab in enumerate(labels)],
        f"{what}: px moved by one sigma{' (* default)' if any(star) else ''}, median per bin",
        "theta (deg from the optical axis)",
        "px per sigma (log)",
        log_y=True,
    )
    return np.vstack([top, bottom])


def third_order_figure(
    p: np.ndarray, theta_max: float, phi: float = -math.pi / 2, lens: Any = None
) -> np.ndarray:
    """Figure 9: px error of dropping k2 theta³ along theta (and, for a Kannala–Brandt
    ``lens``, its whole distance from r = f theta)."""
    th = np.linspace(0.0, theta_max, 200)
    series = [("k2 theta^3", np.degrees(th), third_order_px(th, p, phi))]
    if isinstance(lens, KannalaBrandt) and any(lens.k[1:]):
        f = math.hypot(lens.fx * math.cos(phi), lens.fy * math.sin(phi))
        series.append(
            ("full lens - f theta", np.degrees(th), np.abs(f * (lens.distort_theta(th) - th)))
        )
    return line_plot(
        series,
        f"Third-order term of the lens model (phi = {math.degrees(phi):g} deg)",
        "theta (deg from the optical axis)",
        "error (px)",
        hlines=(1.0, 2.0, 3.0, 4.0),
    )

"""Plausibility bounds on camera data, checked before any image is read.

Values outside these bounds are not measurement noise but a broken export (a zeroed field, a
unit mix-up, a corrupt file); they are reported as one line naming the file and the field
instead of training on them.
"""

from __future__ import annotations

import math

from .errors import SceneError

MAX_COORD = 1e9            # |translation|, |camera centre|: more than a million km in metres
MAX_IMAGE_SIDE = 100_000   # pixels
MAX_DISTORTION = 100.0     # |k1|, |k2|, |p1|, ... (real lenses stay within a few units)
MIN_FOV_DEG, MAX_FOV_DEG = 0.01, 179.0
MIN_TRAIN_SIDE = 32        # a downscale may not leave images smaller than this


def check_size(value, where: str, field: str) -> float:
    """An image side (``field``) in 1..MAX_IMAGE_SIDE pixels."""
    if not (math.isfinite(value) and 1 <= value <= MAX_IMAGE_SIDE):
        raise SceneError(f"{where}: '{field}' is {value:g}, expected an image size of 1..{MAX_IMAGE_SIDE} pixels; "
                         "fix the file")
    return value


def check_angle(value, where: str, field: str) -> float:
    """A field of view in radians, strictly between 0 and pi."""
    lo, hi = math.radians(MIN_FOV_DEG), math.radians(MAX_FOV_DEG)
    if not lo <= value <= hi:
        raise SceneError(f"{where}: '{field}' is {value:g} rad, expected a field of view in radians between "
                         f"{lo:.2g} and {hi:.3g} ({MIN_FOV_DEG:g}..{MAX_FOV_DEG:g} degrees); fix the file")
    return value


def check_focal(focal, side, where: str, field: str) -> float:
    """A pinhole focal length (pixels) giving a field of view within MIN..MAX_FOV_DEG over ``side`` pixels."""
    if not (math.isfinite(focal) and focal > 0):
        raise SceneError(f"{where}: '{field}' is {focal:g}, expected a focal length > 0 pixels; fix the file")
    fov = math.degrees(2 * math.atan(0.5 * side / focal))
    if not MIN_FOV_DEG <= fov <= MAX_FOV_DEG:
        raise SceneError(f"{where}: '{field}' = {focal:g} px over {side:g} px is a field of view of {fov:.3g} "
                         f"degrees, outside {MIN_FOV_DEG:g}..{MAX_FOV_DEG:g}; fix the file")
    return focal


def check_distortion(coeffs: dict, where: str) -> None:
    """Lens distortion coefficients (``name -> value``) within +-MAX_DISTORTION."""
    for name, v in coeffs.items():
        if v is None:
            continue
        if not math.isfinite(v):
            raise SceneError(f"{where}: distortion coefficient '{name}' is not finite; fix the file")
        if abs(v) > MAX_DISTORTION:
            raise SceneError(f"{where}: distortion coefficient '{name}' = {v:g} is implausible (|{name}| <= "
                             f"{MAX_DISTORTION:g} for real lenses); fix the calibration")


def check_translation(t, where: str, what: str = "camera position") -> None:
    """A translation / camera centre with every coordinate within +-MAX_COORD."""
    if max(abs(float(v)) for v in t) > MAX_COORD:
        raise SceneError(f"{where}: {what} {[float(v) for v in t]} is implausibly large (> {MAX_COORD:g} units); "
                         "fix or remove this image")


def check_train_size(width: int, height: int, orig: tuple, downscale: float, where: str) -> None:
    """A downscale must leave images of at least MIN_TRAIN_SIDE pixels on their shorter side."""
    if min(width, height) < MIN_TRAIN_SIDE <= min(orig):
        most = min(orig) / MIN_TRAIN_SIDE
        raise SceneError(f"{where}: --downscale {downscale:g} leaves {width}x{height}-pixel images (from "
                         f"{orig[0]}x{orig[1]}), under {MIN_TRAIN_SIDE} px; use --downscale {max(1.0, math.floor(most)):g} "
                         "or less")

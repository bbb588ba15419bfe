"""Test material for the anonymiser: real faces and rendered plates composited into frames.

Faces are the 100 labelled real faces of scikit-image's LFW subset (`skimage.data.lfw_subset`,
25 x 25 grey crops from brow to chin; shipped inside the wheel). Each is tinted to a skin tone,
set on a head (hair ellipse) and shoulders so a detector sees a person, then posed: roll
(in-plane rotation), yaw (horizontal foreshortening with the face shifted off-centre), mirror,
and motion blur. Plates are rendered: European (white, blue band, "AB 123 CD") and North
American (white, dark characters, "7ABC123") layouts in DejaVu Sans Bold (shipped with
matplotlib), under a small perspective tilt.

`place_face` / `place_plate` paste one object into a BGR frame in place and return its
ground-truth box (x0, y0, x1, y1): the face crop, or the plate rectangle.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np


@dataclass(frozen=True)
class FacePose:
    size: int  # face box width in pixels (brow-to-chin crop)
    roll_deg: float = 0.0
    yaw: float = 0.0  # 0 frontal .. 0.6 strongly turned (horizontal foreshortening)
    mirror: bool = False
    motion_px: int = 0  # horizontal motion-blur length (0 = sharp)


@lru_cache(maxsize=1)
def lfw_faces() -> np.ndarray:
    """The 100 real faces of the LFW subset, uint8 [100, 25, 25] (needs scikit-image)."""
    from skimage.data import lfw_subset

    return (lfw_subset()[:100] * 255).round().astype(np.uint8)


SKIN = np.array([[140, 170, 220], [110, 140, 190], [80, 105, 150], [60, 80, 115]], np.float32)  # BGR
HAIR = np.array([[30, 30, 35], [40, 60, 90], [150, 170, 190], [20, 20, 20]], np.float32)
CLOTH = np.array([[60, 60, 160], [150, 90, 40], [40, 40, 40], [200, 200, 200], [60, 140, 60]], np.float32)


def _motion_blur(img: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return img
    return cv2.filter2D(img, -1, np.full((1, n), 1.0 / n, np.float32))


def person_sprite(face: np.ndarray, pose: FacePose, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, tuple]:
    """A head-and-shoulders sprite: BGR [h, w, 3], alpha [h, w] in [0, 1], face box in it."""
    s = pose.size
    fw = max(4, int(round(s * (1.0 - pose.yaw))))  # foreshortened face width
    grey = cv2.resize(face, (fw, s), interpolation=cv2.INTER_AREA if s < 25 else cv2.INTER_CUBIC)
    if pose.mirror:
        grey = grey[:, ::-1]
    skin = SKIN[rng.integers(len(SKIN))] / 170.0
    rgb = np.clip(grey[:, :, None].astype(np.float32) * skin, 0, 255)
    H, W = int(s * 2.6), int(s * 2.4)
    img = np.zeros((H, W, 3), np.float32)
    alpha = np.zeros((H, W), np.float32)
    cx, cy = W // 2, int(s * 0.85)
    cloth = CLOTH[rng.integers(len(CLOTH))]
    cv2.ellipse(img, (cx, int(s * 2.6)), (int(s * 1.15), int(s * 0.9)), 0, 0, 360, cloth.tolist(), -1)
    cv2.ellipse(alpha, (cx, int(s * 2.6)), (int(s * 1.15), int(s * 0.9)), 0, 0, 360, 1.0, -1)
    cv2.rectangle(img, (cx - s // 5, int(s * 1.4)), (cx + s // 5, int(s * 1.9)), (skin * 150).tolist(), -1)
    cv2.rectangle(alpha, (cx - s // 5, int(s * 1.4)), (cx + s // 5, int(s * 1.9)), 1.0, -1)
    axes = (int(s * 0.62), int(s * 0.78))
    cv2.ellipse(img, (cx, cy), axes, 0, 0, 360, HAIR[rng.integers(len(HAIR))].tolist(), -1)
    cv2.ellipse(alpha, (cx, cy), axes, 0, 0, 360, 1.0, -1)
    shift = int(round(pose.yaw * s * 0.35)) * (-1 if pose.mirror else 1)
    x0, y0 = cx - fw // 2 + shift, cy - s // 2 + int(s * 0.08)
    img[y0:y0 + s, x0:x0 + fw] = rgb
    alpha[y0:y0 + s, x0:x0 + fw] = 1.0
    alpha = cv2.GaussianBlur(alpha, (0, 0), max(0.6, s / 40))  # feathered edges
    box = (x0, y0, x0 + fw, y0 + s)
    if pose.roll_deg:
        M = cv2.getRotationMatrix2D((cx, cy), pose.roll_deg, 1.0)
        img, alpha = cv2.warpAffine(img, M, (W, H)), cv2.warpAffine(alpha, M, (W, H))
        corners = np.array([[box[0], box[1], 1], [box[2], box[1], 1], [box[0], box[3], 1], [box[2], box[3], 1]])
        p = corners @ M.T
        box = (p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max())
    return _motion_blur(img, pose.motion_px), _motion_blur(alpha, pose.motion_px), box


def paste(frame: np.ndarray, sprite: np.ndarray, alpha: np.ndarray, x: int, y: int) -> None:
    """Alpha-blend `sprite` into `frame` (in place) with its top-left corner at (x, y), clipped."""
    H, W = frame.shape[:2]
    h, w = alpha.shape
    a0, b0, a1, b1 = max(0, x), max(0, y), min(W, x + w), min(H, y + h)
    if a1 <= a0 or b1 <= b0:
        return
    a = alpha[b0 - y:b1 - y, a0 - x:a1 - x, None]
    roi = frame[b0:b1, a0:a1].astype(np.float32)
    frame[b0:b1, a0:a1] = np.clip(roi * (1 - a) + sprite[b0 - y:b1 - y, a0 - x:a1 - x] * a + 0.5, 0, 255)


def place_face(frame: np.ndarray, face: np.ndarray, pose: FacePose, x: int, y: int,
               rng: np.random.Generator) -> np.ndarray:
    """Paste a posed person whose sprite's top-left is (x, y); returns the face box [4]."""
    sprite, alpha, box = person_sprite(face, pose, rng)
    paste(frame, sprite, alpha, x, y)
    return np.array(box, np.float64) + [x, y, x, y]


@lru_cache(maxsize=1)
def _plate_font_path() -> str:
    from matplotlib import font_manager

    return font_manager.findfont(font_manager.FontProperties(family="DejaVu Sans", weight="bold"))


def _plate_text(rng: np.random.Generator, layout: str) -> str:
    L = lambda n: "".join(rng.choice(list("ABCDEFGHJKLMNPRSTUVWXYZ"), n))  # noqa: E731
    D = lambda n: "".join(rng.choice(list("0123456789"), n))  # noqa: E731
    return f"{L(2)} {D(3)} {L(2)}" if layout == "eu" else f"{D(1)}{L(3)}{D(3)}"


def plate_sprite(width: int, layout: str, rng: np.random.Generator) -> np.ndarray:
    """A BGR plate image `width` px wide: "eu" (520 x 110 mm) or "us" (12 x 6 in)."""
    from PIL import Image, ImageDraw, ImageFont

    scale = 4  # render large, then shrink (anti-aliased like a camera)
    W, H = width * scale, int(round(width * (110 / 520 if layout == "eu" else 0.5))) * scale
    img = Image.new("RGB", (W, H), (245, 245, 240))
    draw = ImageDraw.Draw(img)
    draw.rectangle([0, 0, W - 1, H - 1], outline=(20, 20, 20), width=max(1, H // 30))
    x0 = 0
    if layout == "eu":
        x0 = int(W * 0.08)
        draw.rectangle([0, 0, x0, H], fill=(40, 60, 170))
    text = _plate_text(rng, layout)
    size = int(H * (0.72 if layout == "eu" else 0.55))
    font = ImageFont.truetype(_plate_font_path(), size)
    tw = draw.textlength(text, font=font)
    if tw > 0.9 * (W - x0):  # fit the text to the plate
        font = font.font_variant(size=int(size * 0.9 * (W - x0) / tw))
        tw = draw.textlength(text, font=font)
    colour = (15, 15, 15) if layout == "eu" else (30, 40, 120)
    draw.text((x0 + (W - x0 - tw) / 2, H / 2), text, fill=colour, font=font, anchor="lm")
    if layout == "us":
        draw.text((W / 2, H * 0.12), "CALIFORNIA", fill=(160, 30, 30), font=font.font_variant(size=H // 7),
                  anchor="mt")
    small = np.asarray(img)[:, :, ::-1]
    return cv2.resize(small, (W // scale, H // scale), interpolation=cv2.INTER_AREA)


def place_plate(frame: np.ndarray, width: int, layout: str, x: int, y: int, rng: np.random.Generator,
                tilt: float = 0.1, motion_px: int = 0) -> np.ndarray:
    """Paste a rendered plate (perspective `tilt`, motion blur) at (x, y); returns its box [4]."""
    plate = plate_sprite(width, layout, rng).astype(np.float32)
    h, w = plate.shape[:2]
    d = tilt * h * rng.uniform(-1, 1)
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    dst = (np.float32([[0, d], [w, -d], [w, h + d], [0, h - d]]) + [0, abs(d)]).astype(np.float32)
    Hm = cv2.getPerspectiveTransform(src, dst)
    out_h = int(np.ceil(h + 2 * abs(d)))
    warped = cv2.warpPerspective(plate, Hm, (w, out_h))
    alpha = cv2.warpPerspective(np.ones((h, w), np.float32), Hm, (w, out_h))
    paste(frame, _motion_blur(warped, motion_px), _motion_blur(alpha, motion_px), x, y)
    return np.array([x, y, x + w, y + out_h], np.float64)


@dataclass
class Composite:
    """A frame with pasted objects and their ground truth (boxes [K, 4] x0, y0, x1, y1)."""

    image: np.ndarray
    faces: np.ndarray  # face crops
    poses: list[FacePose]
    people: np.ndarray  # whole head-and-shoulders sprites (a detection inside one is no false positive)
    plates: np.ndarray


def _free_spot(taken: list, w: int, h: int, W: int, H: int, rng: np.random.Generator) -> tuple[int, int] | None:
    for _ in range(50):
        x, y = int(rng.integers(0, max(1, W - w))), int(rng.integers(0, max(1, H - h)))
        if all(x + w <= a or a + c <= x or y + h <= b or b + d <= y for a, b, c, d in taken):
            taken.append((x, y, w, h))
            return x, y
    return None


def composite(frame: np.ndarray, poses: list[FacePose], plate_widths: list[int],
              rng: np.random.Generator) -> Composite:
    """Paste posed LFW faces and rendered plates at free random spots of a copy of `frame`."""
    img, faces = frame.copy(), lfw_faces()
    H, W = img.shape[:2]
    taken: list = []
    out = Composite(img, np.zeros((0, 4)), [], np.zeros((0, 4)), np.zeros((0, 4)))
    for pose in sorted(poses, key=lambda p: -p.size):  # the largest first, while there is room
        spot = _free_spot(taken, int(pose.size * 2.6), int(pose.size * 2.6), W, H, rng)
        if spot is None:
            continue
        box = place_face(img, faces[rng.integers(len(faces))], pose, spot[0], spot[1], rng)
        out.faces = np.r_[out.faces, box[None]]
        out.people = np.r_[out.people, [[spot[0], spot[1], spot[0] + pose.size * 2.4, spot[1] + pose.size * 2.6]]]
        out.poses.append(pose)
    for w in plate_widths:
        spot = _free_spot(taken, w, w // 2 + 4, W, H, rng)
        if spot is not None:
            box = place_plate(img, w, str(rng.choice(["eu", "us"])), spot[0], spot[1], rng)
            out.plates = np.r_[out.plates, box[None]]
    return out


def coverage(mask: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Fraction of each box [K, 4] that `mask` (bool [H, W]) covers: [K]."""
    out = []
    for x0, y0, x1, y1 in np.asarray(boxes).reshape(-1, 4):
        a, b, c, d = int(max(0, x0)), int(max(0, y0)), int(np.ceil(x1)), int(np.ceil(y1))
        roi = mask[b:d, a:c]
        out.append(float(roi.mean()) if roi.size else 0.0)
    return np.asarray(out)


def false_positives(detections: np.ndarray, objects: np.ndarray) -> int:
    """Detections whose centre lies in none of the object boxes."""
    n = 0
    for x0, y0, x1, y1 in np.asarray(detections).reshape(-1, 4):
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        objs = np.asarray(objects).reshape(-1, 4)
        n += not np.any((objs[:, 0] <= cx) & (cx <= objs[:, 2]) & (objs[:, 1] <= cy) & (cy <= objs[:, 3]))
    return n

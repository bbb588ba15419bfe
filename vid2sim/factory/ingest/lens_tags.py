"""What a source says about its camera, kept in the frames the decode stage writes.

Only the camera's make and model and the 35 mm-equivalent focal length (EXIF 0x010F, 0x0110 and
0xA405) go into the written JPEGs; the rest of a photo's EXIF (GPS, times, serial numbers) does
not. The sfm stage starts its camera model and focal length from them
(`sfm/camera_model.exif_hint`): without them every clip starts from COLMAP's default focal length
(1.2 x the long side, ~45 deg), far from a wide action camera's, and the mapper spends its time
walking there.

Videos: the container's make / model tags (plain, QuickTime, Android), else an action-camera maker
named by the video track's encoder or handler ("GoPro AVC encoder"). Photos: their EXIF.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

MAKE_TAGS = ("make", "com.apple.quicktime.make", "com.android.manufacturer")
MODEL_TAGS = ("model", "com.apple.quicktime.model", "com.android.model")
# makers whose cameras name themselves in the video track's encoder / handler tags
TRACK_MAKERS = ("GoPro", "DJI", "Insta360")
EXIF_MAKE, EXIF_MODEL, EXIF_IFD, EXIF_FOCAL_35MM = 0x010F, 0x0110, 0x8769, 0xA405


@dataclass(frozen=True)
class LensTags:
    make: str = ""
    model: str = ""
    focal_35mm: float = 0.0  # 35 mm-equivalent focal length in mm; 0 = unknown

    @property
    def empty(self) -> bool:
        return not (self.make or self.model or self.focal_35mm)

    def exif_segment(self) -> bytes:
        """A JPEG APP1 segment holding these tags (b"" when there is nothing to say)."""
        if self.empty:
            return b""
        from PIL import Image

        exif = Image.Exif()
        if self.make:
            exif[EXIF_MAKE] = self.make
        if self.model:
            exif[EXIF_MODEL] = self.model
        if self.focal_35mm:
            exif.get_ifd(EXIF_IFD)[EXIF_FOCAL_35MM] = int(round(self.focal_35mm))
        body = exif.tobytes()  # b"Exif\0\0" + TIFF
        return b"\xff\xe1" + (len(body) + 2).to_bytes(2, "big") + body


def _clean(value: object) -> str:
    return str(value or "").strip("\x00\x0b ").strip()


def from_video(path: Path) -> LensTags:
    """The camera tags of a video file's container (no decoding); empty when it names none."""
    import av

    try:
        with av.open(str(path)) as container:
            tags = dict(container.metadata)
            track = dict(container.streams.video[0].metadata) if container.streams.video else {}
    except (av.error.FFmpegError, OSError, ValueError):
        return LensTags()
    make = next((_clean(tags[k]) for k in MAKE_TAGS if _clean(tags.get(k))), "")
    model = next((_clean(tags[k]) for k in MODEL_TAGS if _clean(tags.get(k))), "")
    if not make:
        named = f"{track.get('encoder', '')} {track.get('handler_name', '')}".lower()
        make = next((m for m in TRACK_MAKERS if m.lower() in named), "")
    return LensTags(make, model)


def from_image(path: Path) -> LensTags:
    """Make, model and 35 mm focal length from a photo's EXIF; empty when it has none."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            exif = im.getexif()
            sub = exif.get_ifd(EXIF_IFD) if exif else {}
    except (OSError, ValueError):
        return LensTags()
    focal = sub.get(EXIF_FOCAL_35MM) if sub else None
    return LensTags(_clean(exif.get(EXIF_MAKE)), _clean(exif.get(EXIF_MODEL)),
                    float(focal) if focal else 0.0)


def with_exif(jpeg: bytes, segment: bytes) -> bytes:
    """The JPEG `jpeg` with the APP1 `segment` after its SOI and JFIF APP0 (pixels unchanged)."""
    if not segment:
        return jpeg
    at = 2
    if jpeg[2:4] == b"\xff\xe0":  # JFIF APP0 first, as the JFIF standard wants it
        at = 4 + int.from_bytes(jpeg[4:6], "big")
    return jpeg[:at] + segment + jpeg[at:]

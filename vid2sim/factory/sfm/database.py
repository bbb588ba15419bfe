"""The sfm stage's feature database written in frame order, whatever the extraction's thread count.

COLMAP's feature extractor on several threads computes the same features for each frame as on
one, but hands out image, frame and pose-prior ids in the order the threads finish, so the mapper
would see the frames in a different order on every run. `copy_in_name_order` rewrites such a
database with the ids a one-thread extraction gives (frames in name order, 1, 2, ...): every table
then holds the same rows as after a one-thread extraction.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence


def copy_in_name_order(src: Path, dst: Path, names: Sequence[str]) -> int:
    """Copy cameras, rigs, and each image of `src` named in `names` (in that order) with its frame,
    keypoints, descriptors and pose priors into the new database `dst`; returns the images copied.
    Matches are not copied (run matching after this)."""
    import pycolmap

    if Path(dst).exists():
        raise FileExistsError(f"{dst}: the ordered feature database must be new")
    a, b = pycolmap.Database.open(str(src)), pycolmap.Database.open(str(dst))
    try:
        for camera in a.read_all_cameras():
            b.write_camera(camera, use_camera_id=True)
        for rig in a.read_all_rigs():
            b.write_rig(rig, use_rig_id=True)
        rig_of = {data.id: frame.rig_id for frame in a.read_all_frames() for data in frame.data_ids}
        priors: dict[int, list] = {}
        for prior in a.read_all_pose_priors():
            priors.setdefault(prior.corr_data_id.id, []).append(prior)
        by_name = {image.name: image for image in a.read_all_images()}
        copied = 0
        for name in names:
            old = by_name.get(name)
            if old is None:
                continue
            image_id = b.write_image(pycolmap.Image(name=name, camera_id=old.camera_id))
            data_id = pycolmap.data_t(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, old.camera_id), image_id)
            frame = pycolmap.Frame()
            frame.rig_id = rig_of[old.image_id]
            frame.add_data_id(data_id)
            b.write_frame(frame)
            b.write_keypoints(image_id, a.read_keypoints(old.image_id))
            b.write_descriptors(image_id, a.read_descriptors(old.image_id))
            for prior in priors.get(old.image_id, []):
                prior.corr_data_id = data_id
                b.write_pose_prior(prior)
            copied += 1
    finally:
        a.close()
        b.close()
    return copied

"""KITTI in its two official layouts, auto-detected under ``--kitti-root``.

odometry:  [odometry/]dataset/sequences/NN/{calib.txt, image_0..3/NNNNNN.png},  [odometry/]dataset/poses/NN.txt
raw:       [raw/]DATE/calib_{cam_to_cam,imu_to_velo,velo_to_cam}.txt,  [raw/]DATE/DATE_drive_NNNN_sync/image_0X/data/NNNNNNNNNN.png,
           [raw/]DATE/DATE_drive_NNNN_sync/oxts/data/NNNNNNNNNN.txt

Both are rectified: every camera's projection matrix is P_i = K [I | t_i] in the rectified frame of
camera 0, so a pair's ground truth follows from two projection matrices of one world frame.
Stereo pairs (two cameras, one frame) work in both layouts. Temporal pairs (one camera, frames
t -> t+k) need camera-0 poses (camera 0 -> world): odometry's poses file, or, in a raw drive, the oxts
GPS/IMU packets of both frames, as pykitti and the KITTI devkit derive them (:func:`poses.oxts_imu_poses`,
:func:`calib.cam0_from_imu`). GPS/IMU poses are less accurate than odometry's: a raw temporal pair's
``gt_accuracy_px`` is :data:`poses.OXTS_GT_ACCURACY_PX`.

The modules: files (reading files with one-line errors, images decoded lazily), calib (calibration files: rectified
projections, the unrectified cameras, IMU -> camera), poses (odometry poses files, oxts packets), sequence (a sequence
or drive and its pairs, opened by :func:`open_dataset`).
"""

from fviz.data.kitti.calib import RawCamera, raw_cameras, unrectified_fundamental
from fviz.data.kitti.files import read_image
from fviz.data.kitti.poses import OXTS_GT_ACCURACY_PX, ROTATION_TOL
from fviz.data.kitti.sequence import GT_ACCURACY_PX, PAIR_KINDS, KittiSequence, open_dataset

__all__ = [
    "GT_ACCURACY_PX",
    "OXTS_GT_ACCURACY_PX",
    "PAIR_KINDS",
    "ROTATION_TOL",
    "KittiSequence",
    "RawCamera",
    "open_dataset",
    "raw_cameras",
    "read_image",
    "unrectified_fundamental",
]

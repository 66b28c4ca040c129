"""What the camera says of its storage: STORAGE_INFORMATION and CAMERA_CAPTURE_STATUS's ``available_capacity``.

QGroundControl (src/Camera/VehicleCameraControl.cc, ``handleStorageInfo``/``handleCaptureStatus``) casts
``total_capacity`` and ``available_capacity`` (MiB, floats) to uint32 and shows them as the camera's free space,
taking STORAGE_INFORMATION's values only with ``status`` READY. A NaN became garbage there; so every value here is
a finite number of MiB: the store's disk budget, what its files use, and what is left of it (no more than the
file system has free). Without a store (the link alone) the storage is NOT_SUPPORTED and its capacities 0.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mav

MIB = 1024 * 1024
STORAGE_ID = 1
"""The one storage this camera has (the on-board store); 1-based, as the spec numbers them."""
STORAGE_NAME = b"summary store"


@dataclass(frozen=True)
class StorageSpace:
    """The store's room in bytes: ``total`` its disk budget, ``used`` its files, ``available`` what is left."""

    total: int
    used: int
    available: int


def mib(value: int) -> float:
    """Bytes as the MiB MAVLink carries, never negative."""
    return max(0, int(value)) / MIB


def storage_information(space: StorageSpace | None, time_boot_ms: int) -> mav.MAVLink_storage_information_message:
    """STORAGE_INFORMATION for our one storage: READY with its capacities, or NOT_SUPPORTED (all 0) without one."""
    if space is None:
        return mav.MAVLink_storage_information_message(time_boot_ms & 0xFFFFFFFF, STORAGE_ID, 1,
                                                       mav.STORAGE_STATUS_NOT_SUPPORTED, 0.0, 0.0, 0.0, 0.0, 0.0,
                                                       mav.STORAGE_TYPE_OTHER, STORAGE_NAME)
    return mav.MAVLink_storage_information_message(
        time_boot_ms & 0xFFFFFFFF, STORAGE_ID, 1, mav.STORAGE_STATUS_READY, mib(space.total), mib(space.used),
        mib(space.available), 0.0, 0.0, mav.STORAGE_TYPE_OTHER, STORAGE_NAME)


def available_mib(space: StorageSpace | None) -> float:
    """CAMERA_CAPTURE_STATUS.available_capacity: the store's room left, 0 without a store."""
    return 0.0 if space is None else mib(space.available)

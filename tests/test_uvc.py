"""The D435 over V4L2 without the camera: a fake capture (spec=cv2.VideoCapture) that plays a driver
granting what it can, and the depth node found in a fake /sys/class/video4linux tree."""

from __future__ import annotations

from pathlib import Path
from unittest import mock

import cv2
import numpy as np
import pytest

from quadnav_onboard.sources.uvc import (
    MAX_BUFFER_AGE_S,
    Z16,
    DepthSourceError,
    UvcDepthSource,
    V4l2Mode,
    find_depth_node,
    fourcc_str,
    list_v4l2_nodes,
    raw_to_depth_mm,
)

YUYV = cv2.VideoWriter_fourcc("Y", "U", "Y", "V")
D435_NAME = "Intel(R) RealSense(TM) Depth Ca"  # uvcvideo cuts the product name to 31 characters
DEPTH_MODES = {(424, 240, 30.0), (424, 240, 15.0), (848, 480, 30.0)}


class FakeDriver:
    """A V4L2 driver behind OpenCV: takes a FOURCC it has, snaps size and rate to its nearest mode
    (as VIDIOC_S_FMT / S_PARM do) and says what it took through ``get``."""

    def __init__(self, fourccs: tuple[int, ...] = (Z16,), modes: set[tuple[int, int, float]] = DEPTH_MODES):
        self.fourccs, self.modes = fourccs, modes
        self.props: dict[int, float] = {
            cv2.CAP_PROP_FOURCC: float(fourccs[0]),
            cv2.CAP_PROP_FRAME_WIDTH: 848.0,
            cv2.CAP_PROP_FRAME_HEIGHT: 480.0,
            cv2.CAP_PROP_FPS: 30.0,
            cv2.CAP_PROP_BUFFERSIZE: 4.0,
            cv2.CAP_PROP_POS_MSEC: 0.0,
        }

    def _snap(self, width: float, height: float, fps: float) -> None:
        w, h, f = min(self.modes, key=lambda m: (abs(m[0] - width) + abs(m[1] - height), abs(m[2] - fps)))
        self.props.update({cv2.CAP_PROP_FRAME_WIDTH: w, cv2.CAP_PROP_FRAME_HEIGHT: h, cv2.CAP_PROP_FPS: f})

    def set(self, prop: int, value: float) -> bool:
        p = self.props
        if prop == cv2.CAP_PROP_FOURCC:
            if int(value) not in self.fourccs:
                return False
            p[prop] = float(value)
        elif prop == cv2.CAP_PROP_FRAME_WIDTH:
            self._snap(value, p[cv2.CAP_PROP_FRAME_HEIGHT], p[cv2.CAP_PROP_FPS])
        elif prop == cv2.CAP_PROP_FRAME_HEIGHT:
            self._snap(p[cv2.CAP_PROP_FRAME_WIDTH], value, p[cv2.CAP_PROP_FPS])
        elif prop == cv2.CAP_PROP_FPS:
            self._snap(p[cv2.CAP_PROP_FRAME_WIDTH], p[cv2.CAP_PROP_FRAME_HEIGHT], value)
        else:
            p[prop] = float(value)
        return True  # OpenCV's V4L2 backend reports success for a size or rate it snapped

    def get(self, prop: int) -> float:
        return self.props.get(prop, 0.0)

    def capture(self, frames: list[tuple[bool, np.ndarray | None]], stamps_ms: list[float] | None = None):
        """A fake cv2.VideoCapture over this driver; each read sets POS_MSEC from ``stamps_ms``."""
        cap = mock.create_autospec(cv2.VideoCapture, instance=True)
        cap.isOpened.return_value = True
        cap.set.side_effect = self.set
        cap.get.side_effect = self.get
        reads = iter(frames)
        stamps = iter(stamps_ms or [])

        def read() -> tuple[bool, np.ndarray | None]:
            self.props[cv2.CAP_PROP_POS_MSEC] = next(stamps, 0.0)
            return next(reads)

        cap.read.side_effect = read
        return cap


def z16(value: int = 1234, width: int = 424, height: int = 240) -> np.ndarray:
    """A Z16 frame as OpenCV hands raw buffers over: flat bytes."""
    return np.full((height, width), value, np.uint16).view(np.uint8).reshape(1, -1)


def test_raw_z16_bytes_become_uint16_millimetres() -> None:
    """Both raw layouts OpenCV uses become (H, W) uint16; an RGB frame is refused, hinting why."""
    depth = np.arange(32 * 40, dtype=np.uint16).reshape(32, 40) * 7
    raw = depth.astype("<u2").view(np.uint8).reshape(1, -1)
    assert np.array_equal(raw_to_depth_mm(raw, 40, 32), depth)
    assert raw_to_depth_mm(depth, 40, 32) is depth
    with pytest.raises(ValueError, match="RGB"):
        raw_to_depth_mm(np.zeros((32, 40, 3), np.uint8), 40, 32)


def test_fourcc_codes_read_back_as_text() -> None:
    assert fourcc_str(float(Z16)) == "Z16 " and fourcc_str(YUYV) == "YUYV"
    assert fourcc_str(0) == "?" and fourcc_str(-1) == "?"


async def test_a_granted_mode_opens_with_raw_z16_and_a_short_queue() -> None:
    """Asked Z16 424x240 @ 30 of a driver that has it: opened, raw buffers, 2 V4L2 buffers, and frames
    are (240, 424) uint16 millimetres."""
    driver = FakeDriver()
    cap = driver.capture([(True, z16())] * 3)
    factory = mock.Mock(return_value=cap)
    async with UvcDepthSource("/dev/video2", 424, 240, 30, capture_factory=factory) as src:
        f = await anext(src.frames())
    factory.assert_called_once_with("/dev/video2", cv2.CAP_V4L2)
    assert src.granted == V4l2Mode("Z16 ", 424, 240, 30.0) and src.opened_device == "/dev/video2"
    props = {c.args[0]: c.args[1] for c in cap.set.call_args_list}
    assert props[cv2.CAP_PROP_CONVERT_RGB] == 0 and props[cv2.CAP_PROP_FORMAT] == -1
    assert props[cv2.CAP_PROP_BUFFERSIZE] == 2
    order = [c.args[0] for c in cap.set.call_args_list]
    assert order.index(cv2.CAP_PROP_FOURCC) < order.index(cv2.CAP_PROP_FRAME_WIDTH)
    assert f.depth_mm.dtype == np.uint16 and f.depth_mm.shape == (240, 424) and f.seq == 1
    assert int(f.depth_mm[0, 0]) == 1234


@pytest.mark.parametrize(
    ("driver", "asked", "granted"),
    [
        # a D435 on USB 2: no 30 Hz at this size; the driver snaps to 15 Hz and set() says True
        (FakeDriver(modes={(424, 240, 15.0)}), (424, 240, 30.0), "Z16 424x240 @ 15 Hz"),
        # a size the camera lacks: the nearest one is granted
        (FakeDriver(), (640, 480, 30.0), "Z16 848x480 @ 30 Hz"),
        # the colour node: no Z16, set(FOURCC) is refused and YUYV stays
        (FakeDriver(fourccs=(YUYV,), modes={(424, 240, 30.0)}), (424, 240, 30.0), "YUYV 424x240 @ 30 Hz"),
    ],
)
async def test_less_than_asked_is_refused_naming_asked_and_granted(
    driver: FakeDriver, asked: tuple[int, int, float], granted: str
) -> None:
    """A driver that grants another mode than the one asked: the source does not start; the error
    names the device, the asked and the granted mode, and the capture is released."""
    cap = driver.capture([])
    w, h, fps = asked
    with pytest.raises(DepthSourceError) as err:
        async with UvcDepthSource("/dev/video4", w, h, fps, capture_factory=mock.Mock(return_value=cap)):
            pass
    msg = str(err.value)
    assert msg.startswith("depth.device '/dev/video4': asked Z16 ")
    assert f"asked Z16 {w}x{h} @ {fps:g} Hz" in msg and f"granted {granted}" in msg
    assert ("set refused: fourcc" in msg) == (granted.startswith("YUYV"))
    cap.release.assert_called_once_with()
    cap.read.assert_not_called()


async def test_capture_time_is_the_driver_buffer_timestamp_when_plausible() -> None:
    """POS_MSEC on the monotonic clock (before the arrival, within MAX_BUFFER_AGE_S) is the capture
    time; zero (no timestamp) or one from another clock falls back to the arrival time."""
    arrival_s = 1000.0
    stamps_ms = [arrival_s * 1e3 - 35.0, 0.0, (arrival_s - MAX_BUFFER_AGE_S - 1.0) * 1e3, 1.7e12]
    cap = FakeDriver().capture([(True, z16())] * 4, stamps_ms)
    src = UvcDepthSource("/dev/video2", capture_factory=mock.Mock(return_value=cap), clock=lambda: arrival_s)
    async with src:
        frames = src.frames()
        first = await anext(frames)
        assert first.t_capture_mono_s == pytest.approx(arrival_s - 0.035) and src.timestamps == "driver"
        rest = [await anext(frames) for _ in range(3)]
    assert [f.t_capture_mono_s for f in rest] == [arrival_s] * 3 and src.timestamps == "arrival"
    assert [f.seq for f in [first, *rest]] == [1, 2, 3, 4]


async def test_device_index_and_open_failure_are_named() -> None:
    cap = mock.create_autospec(cv2.VideoCapture, instance=True)
    cap.isOpened.return_value = False
    factory = mock.Mock(return_value=cap)
    with pytest.raises(DepthSourceError, match="'2'"):
        async with UvcDepthSource("2", capture_factory=factory):
            pass
    factory.assert_called_once_with(2, cv2.CAP_V4L2)


async def test_gives_up_after_repeated_read_failures() -> None:
    cap = FakeDriver().capture([(False, None)] * 5)
    async with UvcDepthSource(
        "/dev/video0", capture_factory=mock.Mock(return_value=cap), max_consecutive_failures=5
    ) as src:
        with pytest.raises(DepthSourceError, match="5 reads in a row"):
            await anext(src.frames())


# --- the depth node ---------------------------------------------------------------------------


def fake_sysfs(root: Path, nodes: dict[str, str]) -> Path:
    """/sys/class/video4linux with one folder per node holding its ``name`` file."""
    sysfs = root / "sys" / "class" / "video4linux"
    for node, name in nodes.items():
        (sysfs / node).mkdir(parents=True)
        (sysfs / node / "name").write_text(name + "\n")
    return sysfs


# A D435 (depth: Z16 and the infrared formats; its metadata node; colour; its metadata node) next to
# a laptop webcam, numbered as uvcvideo does, the webcam first.
D435_FORMATS = {
    "/dev/video0": ["YUYV", "MJPG"],
    "/dev/video1": [],
    "/dev/video2": ["Z16 ", "GREY", "Y8I ", "Y12I"],
    "/dev/video3": [],
    "/dev/video4": ["YUYV"],
    "/dev/video5": [],
}
D435_NODES = {
    "video0": "Integrated Camera: Integrated C",
    "video1": "Integrated Camera: Integrated C",
    "video2": D435_NAME,
    "video3": D435_NAME,
    "video4": D435_NAME,
    "video5": D435_NAME,
}


def test_nodes_are_listed_in_number_order(tmp_path: Path) -> None:
    sysfs = fake_sysfs(tmp_path, {"video10": D435_NAME, "video2": D435_NAME, "v4l-subdev0": "x"})
    assert [n.node for n in list_v4l2_nodes(sysfs, Path("/dev"))] == ["video2", "video10"]
    assert list_v4l2_nodes(tmp_path / "missing") == []


def test_the_depth_node_is_the_realsense_node_offering_z16(tmp_path: Path) -> None:
    """Of six nodes, the one named RealSense that offers Z16 is picked; the webcam is never opened."""
    sysfs = fake_sysfs(tmp_path, D435_NODES)
    opened: list[str] = []

    def formats(device: str) -> list[str]:
        opened.append(device)
        return D435_FORMATS[device]

    assert find_depth_node(sysfs_root=sysfs, list_formats=formats) == "/dev/video2"
    assert "/dev/video0" not in opened and "/dev/video1" not in opened


def test_no_depth_node_is_refused_listing_what_was_seen(tmp_path: Path) -> None:
    """Without the camera (or without access to it) the error lists every node and its formats."""
    sysfs = fake_sysfs(tmp_path, {k: v for k, v in D435_NODES.items() if k in ("video0", "video4")})

    def formats(device: str) -> list[str]:
        if device == "/dev/video4":
            raise PermissionError(13, "Permission denied")
        return D435_FORMATS[device]

    with pytest.raises(DepthSourceError) as err:
        find_depth_node(sysfs_root=sysfs, list_formats=formats)
    msg = str(err.value)
    assert msg.startswith("depth.device 'auto': no V4L2 node named *RealSense* offering Z16")
    assert "/dev/video0 (Integrated Camera" in msg and "/dev/video4" in msg and "Permission denied" in msg


def test_two_cameras_are_refused_naming_both(tmp_path: Path) -> None:
    nodes = {**D435_NODES, "video6": D435_NAME}
    formats = {**D435_FORMATS, "/dev/video6": ["Z16 "]}
    with pytest.raises(DepthSourceError, match=r"2 nodes .*/dev/video2, /dev/video6.*set depth.device"):
        find_depth_node(sysfs_root=fake_sysfs(tmp_path, nodes), list_formats=formats.__getitem__)


async def test_auto_opens_the_node_found(tmp_path: Path) -> None:
    """``device: auto`` opens the discovered node and names it in later errors."""
    sysfs = fake_sysfs(tmp_path, D435_NODES)
    cap = FakeDriver().capture([(True, z16())])
    factory = mock.Mock(return_value=cap)
    src = UvcDepthSource(
        "auto", capture_factory=factory, sysfs_root=sysfs, list_formats=D435_FORMATS.__getitem__
    )
    async with src:
        await anext(src.frames())
    factory.assert_called_once_with("/dev/video2", cv2.CAP_V4L2)
    assert src.opened_device == "/dev/video2"

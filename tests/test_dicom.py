"""DICOM export of a view's clip, read back with pydicom and with icenav's reader."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pydicom
import pytest

from icenav.dicom import PRIVATE_CREATOR, export_view_clip, main, read_view_clip
from icenav.errors import FileFormatError, InvalidValueError, ShapeError
from icenav.kinematics import forward
from icenav.sim.anatomy import EXAMPLE_VIEWS, tip2anatomy
from icenav.sim.ultrasound import UltrasoundRenderer


@pytest.fixture(scope="module")
def clip() -> dict:
    r = UltrasoundRenderer()
    q = np.asarray(EXAMPLE_VIEWS["aortic_valve"])
    period = r.phantom.motion.period_s
    n = 6
    frames = [r.render(tip2anatomy(q), k * period / n) for k in range(n)]
    return {
        "frames": np.stack([f.image for f in frames]),
        "phases": np.array([f.cardiac_phase for f in frames]),
        "frame_time_s": period / n,
        "q_motor": q + np.array([0.01, -0.02, 0.03, 0.5]),
        "tip2base": forward(q),
        "pixel_mm": r.config.pixel_mm,
    }


def test_round_trip_with_pydicom_and_icenav_reader(clip: dict, tmp_path: Path) -> None:
    when = dt.datetime(2026, 11, 22, 5, 30, 12, 345678, tzinfo=dt.UTC)
    path = export_view_clip(
        tmp_path / "aortic.dcm",
        clip["frames"],
        clip["frame_time_s"],
        clip["q_motor"],
        clip["tip2base"],
        acquired_at=when,
        view_name="aortic valve",
        pixel_mm=clip["pixel_mm"],
        cardiac_phases=clip["phases"],
    )
    ds = pydicom.dcmread(path)
    assert ds.SOPClassUID == "1.2.840.10008.5.1.4.1.1.3.1"
    assert ds.file_meta.MediaStorageSOPClassUID == ds.SOPClassUID
    assert ds.Modality == "US"
    assert int(ds.NumberOfFrames) == clip["frames"].shape[0]
    assert float(ds.FrameTime) == pytest.approx(clip["frame_time_s"] * 1000.0, rel=1e-5)
    assert ds.AcquisitionDateTime.startswith("20261122053012.345678")
    np.testing.assert_array_equal(ds.pixel_array, clip["frames"])  # pydicom's own decoder
    block = ds.private_block(0x0011, PRIVATE_CREATOR)
    np.testing.assert_allclose(list(block[0x01].value), clip["q_motor"])
    assert "aortic valve" in ds.ImageComments

    back = read_view_clip(path)
    np.testing.assert_array_equal(back.frames, clip["frames"])
    assert back.frame_time_s == pytest.approx(clip["frame_time_s"], rel=1e-5)
    np.testing.assert_array_equal(back.q_motor, clip["q_motor"])
    np.testing.assert_array_equal(back.tip2base, clip["tip2base"])
    assert back.acquired_at == when
    assert back.view_name == "aortic valve"
    assert back.pixel_mm == pytest.approx(clip["pixel_mm"])
    assert back.cardiac_phases is not None
    np.testing.assert_array_equal(back.cardiac_phases, clip["phases"])


def test_bad_clips_are_rejected(clip: dict, tmp_path: Path) -> None:
    args = (clip["frame_time_s"], clip["q_motor"], clip["tip2base"])
    with pytest.raises(InvalidValueError, match="uint8"):
        export_view_clip(tmp_path / "a.dcm", clip["frames"].astype(float), *args)
    with pytest.raises(ShapeError, match="n_frames, rows, cols"):
        export_view_clip(tmp_path / "a.dcm", clip["frames"][0], *args)
    with pytest.raises(ShapeError, match="cardiac_phases"):
        export_view_clip(tmp_path / "a.dcm", clip["frames"], *args, cardiac_phases=[0.1])
    with pytest.raises(InvalidValueError, match="frame_time_s"):
        export_view_clip(tmp_path / "a.dcm", clip["frames"], 0.0, *args[1:])


def test_reader_rejects_other_files(clip: dict, tmp_path: Path) -> None:
    junk = tmp_path / "junk.dcm"
    junk.write_bytes(b"not a dicom file at all" * 10)
    with pytest.raises(FileFormatError, match="not a readable DICOM"):
        read_view_clip(junk)
    # a valid DICOM of another SOP class
    path = export_view_clip(
        tmp_path / "x.dcm", clip["frames"], clip["frame_time_s"], clip["q_motor"], np.eye(4)
    )
    ds = pydicom.dcmread(path)
    ds.SOPClassUID = "1.2.840.10008.5.1.4.1.1.6.1"  # single-frame US
    ds.save_as(tmp_path / "y.dcm")
    with pytest.raises(FileFormatError, match="Multi-frame"):
        read_view_clip(tmp_path / "y.dcm")


def test_main_exports_an_npz_clip(
    clip: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    npz = tmp_path / "clip.npz"
    np.savez(
        npz,
        frames=clip["frames"],
        frame_time_s=clip["frame_time_s"],
        q_motor=clip["q_motor"],
        tip2base=clip["tip2base"],
        view_name="mitral",
    )
    out = tmp_path / "out.dcm"
    assert main([str(npz), str(out)]) == 0
    assert "6 frames" in capsys.readouterr().out
    assert read_view_clip(out).view_name == "mitral"
    np.savez(tmp_path / "bad.npz", frames=clip["frames"])
    assert main([str(tmp_path / "bad.npz"), str(tmp_path / "bad.dcm")]) == 2
    assert "lacks" in capsys.readouterr().err

"""DICOM export of a view's clip, read back with pydicom and with icenav's reader; the export
directory that no client-given name can leave."""

from __future__ import annotations

import dataclasses
import datetime as dt
import os
import re
import tempfile
from pathlib import Path

import numpy as np
import pydicom
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from icenav.errors import (
    ConfigurationError,
    ExportError,
    FileFormatError,
    InvalidValueError,
    ShapeError,
    UnsafeExportPathError,
)
from icenav.geometry.kinematics import forward
from icenav.persistence.dicom import (
    PRIVATE_CREATOR,
    ExportDirectory,
    ViewClip,
    export_file_stem,
    export_view_clip,
    main,
    read_view_clip,
)
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


# ------------------------------------------------------------------ the export directory

# names a client might send: path tricks, separators, unicode, control characters, very long
TRICKY_NAMES = [
    "../../etc/passwd",
    "/etc/passwd",
    "..",
    ".",
    "",
    "   ",
    ".hidden",
    "a/b\\c",
    "C:\\Windows\\system32",
    "x\x00y",
    "~/evil",
    "Aortenklappe \u00fc",
    "\u2215etc\u2215passwd",  # division slash, looks like '/'
    "\uff0e\uff0e\uff0fx",  # fullwidth '../' (NFKC would make it '../')
    "a" * 5000,
    "\u0301" * 10,  # combining marks only
]
STEM = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]*$|^view$")
FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,47}_\d{8}T\d{6}Z(-\d+)?\.dcm$")
WHEN = dt.datetime(2026, 11, 22, 7, 50, 1, tzinfo=dt.UTC)


def _assert_inside(path: Path, root: Path) -> None:
    assert path.parent == root.resolve()
    assert FILE_NAME.match(path.name), path.name
    assert len(path.name.encode()) <= 80
    assert os.path.realpath(path) == str(path)  # no symlink on the way


TINY = ViewClip(np.zeros((1, 4, 4), np.uint8), 0.05, WHEN, np.zeros(4), np.eye(4))


@settings(max_examples=200, deadline=None)
@given(name=st.text(max_size=300) | st.sampled_from(TRICKY_NAMES))
def test_no_view_name_escapes_the_export_directory(name: str) -> None:
    stem = export_file_stem(name)
    assert STEM.match(stem) and len(stem) <= 48, stem
    with tempfile.TemporaryDirectory() as tmp:
        top = Path(tmp)
        exports = ExportDirectory(top / "session" / "exports")
        path = exports.path_for(name, WHEN)
        _assert_inside(path, top / "session" / "exports")
        assert path.name.startswith(f"{stem}_20261122T075001Z")
        written = exports.write_clip(dataclasses.replace(TINY, view_name=name), WHEN)
        assert written == path
        _assert_inside(written, exports.root)
        files = [p for p in top.rglob("*") if not p.is_dir()]
        assert files == [written]  # the one file, in the directory, nothing elsewhere
        assert read_view_clip(written).view_name == name[:1024]


def test_stems_keep_what_is_safe() -> None:
    assert export_file_stem("apex view-2") == "apex_view-2"
    assert export_file_stem("Aortenklappe \u00fc") == "Aortenklappe_u"
    assert export_file_stem("../../etc/passwd") == "etc_passwd"
    assert export_file_stem("..") == "view" and export_file_stem("") == "view"
    assert export_file_stem("a" * 100, max_chars=10) == "a" * 10
    with pytest.raises(InvalidValueError, match="max_chars"):
        export_file_stem("x", max_chars=0)
    with pytest.raises(ConfigurationError, match="max_stem_chars"):
        ExportDirectory(Path("exports"), max_stem_chars=0)


def test_writes_land_in_the_directory_and_read_back(clip: dict, tmp_path: Path) -> None:
    exports = ExportDirectory(tmp_path / "exports")
    assert not exports.root.exists()  # made on the first export
    view = ViewClip(
        frames=clip["frames"],
        frame_time_s=clip["frame_time_s"],
        acquired_at=WHEN,
        q_motor=clip["q_motor"],
        tip2base=clip["tip2base"],
        view_name="../../x",
        pixel_mm=clip["pixel_mm"],
    )
    written = [exports.write_clip(view, WHEN) for _ in range(3)]
    assert [p.name for p in written] == [
        "x_20261122T075001Z.dcm",
        "x_20261122T075001Z-2.dcm",
        "x_20261122T075001Z-3.dcm",
    ]
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == sorted(
        p.name for p in written
    )  # nothing anywhere else
    ds = pydicom.dcmread(written[0])
    np.testing.assert_array_equal(ds.pixel_array, clip["frames"])
    assert read_view_clip(written[2]).view_name == "../../x"  # the name is data inside


def test_a_planted_symlink_is_never_written_through(clip: dict, tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    exports = ExportDirectory(tmp_path / "exports")
    exports.root.mkdir()
    # someone who can write in the export directory plants the next file name as a symlink
    (exports.root / "apex_20261122T075001Z.dcm").symlink_to(victim)
    (exports.root / "apex_20261122T075001Z-2.dcm").symlink_to(tmp_path / "dangling")
    view = ViewClip(
        clip["frames"], clip["frame_time_s"], WHEN, clip["q_motor"], clip["tip2base"], "apex"
    )
    path = exports.write_clip(view, WHEN)
    assert path.name == "apex_20261122T075001Z-3.dcm" and not path.is_symlink()
    assert victim.read_text() == "precious" and not (tmp_path / "dangling").exists()


def test_a_directory_replaced_by_a_symlink_is_refused(clip: dict, tmp_path: Path) -> None:
    exports = ExportDirectory(tmp_path / "exports")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (tmp_path / "exports").symlink_to(elsewhere, target_is_directory=True)
    view = ViewClip(
        clip["frames"], clip["frame_time_s"], WHEN, clip["q_motor"], clip["tip2base"], "apex"
    )
    with pytest.raises(UnsafeExportPathError, match="replaced by a symlink"):
        exports.write_clip(view, WHEN)
    assert list(elsewhere.iterdir()) == []
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigurationError, match="not a directory"):
        ExportDirectory(tmp_path / "file")


def test_an_unmakeable_directory_is_a_clear_error(clip: dict, tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    exports = ExportDirectory(tmp_path / "file" / "exports")  # below a plain file
    view = ViewClip(
        clip["frames"], clip["frame_time_s"], WHEN, clip["q_motor"], clip["tip2base"], "apex"
    )
    with pytest.raises(ExportError, match="cannot make the export directory"):
        exports.write_clip(view, WHEN)


def test_long_and_odd_view_names_make_valid_dicom(clip: dict, tmp_path: Path) -> None:
    name = "a" * 200 + "\\b\u00fc\x00"
    path = export_view_clip(
        tmp_path / "n.dcm", clip["frames"][:1], 0.05, clip["q_motor"], clip["tip2base"],
        view_name=name,
    )  # fmt: skip
    ds = pydicom.dcmread(path)
    assert len(ds.SeriesDescription) <= 64 and "\\" not in str(ds.SeriesDescription)
    assert read_view_clip(path).view_name == name

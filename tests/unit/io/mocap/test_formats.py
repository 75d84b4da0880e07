"""The format registry: one entry per format, detection in order, config checks of mocap.format."""

import pytest

from cvsflow.exceptions import ConfigError
from cvsflow.io.mocap.formats import BY_KEY, FORMATS, REGISTRY, mocap_settings, read_mocap


def test_registry_keys_are_unique_and_kinds_known():
    """Each format once, with a title and a kind the entry points know."""
    keys = [f.key for f in REGISTRY]
    assert len(keys) == len(set(keys)) and set(FORMATS) == set(keys) == set(BY_KEY)
    assert {f.kind for f in REGISTRY} == {"markers", "poses"}
    assert all(f.read_stream is not None for f in REGISTRY if f.kind == "poses")


def test_a_new_format_is_one_entry(tmp_path, monkeypatch):
    """A made-up format added to the registry alone is detected and read by read_mocap."""
    from cvsflow.io.mocap import formats
    from cvsflow.io.mocap.markers import MocapExport, MocapFormat

    fake = MocapFormat("fake", "Fake export", "markers", lambda head: "FAKE" if head.raw.startswith(b"FAKE") else None,
                       lambda path: MocapExport(path, "fake", 1.0, None))  # fmt: skip
    monkeypatch.setattr(formats, "REGISTRY", (*formats.REGISTRY, fake))
    p = tmp_path / "x.fake"
    p.write_text("FAKE\n")
    assert read_mocap(p).format == "fake"


def test_mocap_format_in_a_session_config():
    """A marker format passes; a pose stream's key and an unknown key are ConfigErrors naming the key."""
    cfg = {"markers": {"camera": {"names": ["a"]}, "board": {"names": ["b"]}}, "mocap": {"format": "c3d"}}
    assert mocap_settings("s", cfg)["format"] == "c3d"
    cfg["mocap"]["format"] = "eth"
    with pytest.raises(ConfigError, match=r"sessions\.s\.mocap\.format: 'eth' is an ETH .*poses of one body"):
        mocap_settings("s", cfg)
    cfg["mocap"]["format"] = "vicom"
    with pytest.raises(ConfigError, match="'vicom' is unknown; expected auto or .*vicon_csv"):
        mocap_settings("s", cfg)

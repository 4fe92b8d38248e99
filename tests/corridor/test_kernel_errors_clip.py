"""Error messages quote user values cut to a bound; a path keeps its file name."""

from __future__ import annotations

from corridor.errors import clip, clip_path


def test_a_long_path_is_cut_at_its_start_and_keeps_its_name() -> None:
    path = "/tmp/" + "deep/" * 40 + "network.net.xml"
    text = clip_path(path, 80)
    assert len(text) <= 80 and text.endswith("network.net.xml'") and text.startswith("'…")
    assert clip_path("/tmp/n.net.xml") == repr("/tmp/n.net.xml")
    assert not clip(path, 80).endswith("network.net.xml'")  # why clip_path exists

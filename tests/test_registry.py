"""Plugin discovery: built-ins through entry points, broken plugins reported not fatal."""

from __future__ import annotations

import types
from pathlib import Path

import pytest

from lwbench import RepresentationCodec, hookimpl, hookspecs
from lwbench.registry import PluginError, get_registry, new_registry

REPO = Path(__file__).resolve().parents[1]


def test_every_plugin_folder_is_registered_through_an_entry_point():
    reg = get_registry()
    assert reg.failures == [], [f.error for f in reg.failures]
    folders = sorted(p.name for p in (REPO / "plugins").iterdir() if (p / "__init__.py").exists())
    registered = {v.split("(")[-1].rstrip(")") for v in reg.providers.values()}
    assert set(folders) <= registered, f"not registered: {set(folders) - registered}"


def test_built_in_metrics_cover_the_frame_metric_ids_of_the_design():
    ids = set(get_registry().metric_ids())
    assert {"bytes", "ratio", "bits_per_point", "link_kbps", "range_rmsd", "coverage", "false_returns",
            "chamfer", "hausdorff", "d1_psnr", "d2_psnr", "points_in", "points_out", "encode_ms",
            "decode_ms", "select_ms", "peak_mb"} <= ids


def test_every_hookspec_is_implemented_by_some_built_in():
    reg = get_registry()
    specs = [n for n in dir(hookspecs) if n.startswith("lwbench_")]
    for name in specs:
        assert getattr(reg.pm.hook, name).get_hookimpls(), f"no built-in implements {name}"


def test_plugin_that_raises_on_import_is_reported_and_skipped(monkeypatch):
    import importlib.metadata as md

    good = md.EntryPoint("raw", "lwbench_plugins.raw", "lwbench")
    bad = md.EntryPoint("broken", "lwbench_no_such_module_xyz", "lwbench")
    monkeypatch.setattr(md, "entry_points", lambda group: [good, bad])
    reg = new_registry()
    assert "raw" in reg.codecs
    assert [f.plugin for f in reg.failures] == ["broken"]
    assert "ModuleNotFoundError" in reg.failures[0].error
    with pytest.raises(PluginError, match="broken"):
        new_registry(strict=True)


def test_misnamed_hook_is_a_failure_not_silence():
    plugin = types.SimpleNamespace()

    @hookimpl
    def lwbench_codec():  # typo: the spec is lwbench_codecs
        return []

    plugin.lwbench_codec = lwbench_codec
    reg = new_registry(load=False)
    assert not reg.register(plugin, "typo")
    assert reg.failures and "lwbench_codec" in reg.failures[0].error


def test_duplicate_codec_name_is_rejected():
    class Dup(RepresentationCodec):
        name = "raw"

        def encode(self, frame):
            return b""

        def decode(self, data):
            return None

    mod = types.SimpleNamespace(lwbench_codecs=hookimpl(lambda: [Dup]))
    reg = new_registry()
    assert not reg.register(mod, "dup")
    assert "already provided" in reg.failures[-1].error
    assert reg.codecs["raw"] is not Dup


def test_unknown_codec_error_lists_the_available_ones():
    with pytest.raises(PluginError, match="available: .*raw"):
        get_registry().codec("nope")

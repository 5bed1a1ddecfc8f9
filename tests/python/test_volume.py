"""The volumetric body from Python: tet meshes, the FEM avatar's data and its cache."""
import numpy as np
import pytest

import flsh


def _soft_avatar(body, betas, cache_dir):
    avatar = flsh.SoftAvatar(body, betas, cache_dir=str(cache_dir))
    avatar.enable_soft_tissue()
    avatar.init_volumetric_data()
    return avatar


def test_tetrahedralize_surface_keeps_the_surface(body):
    nodes, tets, quality = flsh.tetrahedralize_surface(body.v_template, body.faces, resolution=0.5)
    V = body.v_template.shape[0]
    assert nodes.shape[1] == 3 and nodes.shape[0] > V
    np.testing.assert_array_equal(nodes[:V], body.v_template)
    assert tets.shape[1] == 4 and tets.dtype == np.int32
    a, b, c, d = (nodes[tets[:, k]] for k in range(4))
    volumes = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6
    assert volumes.min() > 0
    # The tets fill the body: their volume is the enclosed volume of the surface.
    f = body.faces
    p, q, r = (body.v_template[f[:, k]] for k in range(3))
    enclosed = np.einsum("ij,ij->i", p, np.cross(q, r)).sum() / 6
    assert volumes.sum() == pytest.approx(enclosed, rel=1e-10)
    assert 0 < quality["min_dihedral_deg"] < 70.6 < quality["max_dihedral_deg"] < 180
    raw_nodes, raw_tets, raw_quality = flsh.tetrahedralize_surface(
        body.v_template, body.faces, resolution=0.5, improve_quality=False)
    np.testing.assert_array_equal(raw_nodes[:V], body.v_template)
    assert quality["min_dihedral_deg"] >= raw_quality["min_dihedral_deg"]
    with pytest.raises(ValueError, match="faces"):
        flsh.tetrahedralize_surface(body.v_template, body.faces[:, :2])
    with pytest.raises(ValueError, match="open|boundary|edge"):
        flsh.tetrahedralize_surface(body.v_template, body.faces[1:])


def test_fem_avatar_data_agrees_with_the_body_and_comes_back_from_the_cache(body, tmp_path):
    betas = np.zeros(10)
    betas[:2] = [0.5, -0.4]
    avatar = _soft_avatar(body, betas, tmp_path)
    report = avatar.build_report
    assert not report["template_from_cache"] and report["seconds_meshing"] > 0
    d = avatar.volumetric_data
    V = d.num_surface_nodes
    assert V == body.v_template.shape[0]
    np.testing.assert_allclose(d.rest_nodes[:V], avatar.rest_vertices, atol=1e-12)
    np.testing.assert_allclose(d.weights.sum(axis=1), 1.0, atol=1e-12)
    assert d.weights.shape == (d.num_nodes, 24) and d.shapedirs.shape == (3 * d.num_nodes, 10)
    assert d.posedirs.shape == (3 * d.num_nodes, 207)
    assert d.tets.shape == (d.num_tets, 4)
    assert 0 < d.num_bone_nodes < d.num_nodes - V
    # Surface nodes are soft, except anchors of thin parts the coarse interior misses.
    assert np.mean(d.bone_of_node[:V] == -1) > 0.9
    assert np.all((1000 <= d.density) & (d.density <= 1100))
    assert np.all(d.young > 0) and np.all((0 < d.poisson) & (d.poisson < 0.5))
    frames = d.frames
    np.testing.assert_allclose(np.einsum("tji,tjk->tik", frames, frames),
                               np.broadcast_to(np.eye(3), frames.shape), atol=1e-12)
    assert d.total_mass == pytest.approx(1040 * avatar.volume, rel=0.04)

    again = _soft_avatar(body, betas, tmp_path)
    assert again.build_report["template_from_cache"] and again.build_report["data_from_cache"]
    e = again.volumetric_data
    np.testing.assert_array_equal(e.rest_nodes, d.rest_nodes)
    np.testing.assert_array_equal(e.young, d.young)

    other = _soft_avatar(body, np.array([0.5, 1.5]), tmp_path)
    assert other.build_report["template_from_cache"] and not other.build_report["data_from_cache"]
    assert np.abs(other.volumetric_data.young - d.young).max() > 0


def test_avatar_cli_prints_json_statistics(tmp_path):
    import json
    import os
    import subprocess

    out = subprocess.run([os.environ["FLSH_BIN"], "avatar", "--model", "synthetic:700", "--soft",
                          "fem", "--cache", str(tmp_path), "--betas", "0.3,-0.2"],
                         capture_output=True, text=True, check=True)
    stats = json.loads(out.stdout)
    assert stats["surface_nodes"] == 700 and stats["nodes"] > 700 and stats["tets"] > 0
    assert stats["cache"]["template"] == "miss" and stats["bone_nodes"] > 0
    assert stats["quality"]["min_dihedral_deg"] > 0 and stats["total_mass_kg"] > 0
    assert stats["seconds"]["meshing"] > 0
    again = json.loads(subprocess.run(
        [os.environ["FLSH_BIN"], "avatar", "--model", "synthetic:700", "--soft", "fem", "--cache",
         str(tmp_path), "--betas", "0.3,-0.2"], capture_output=True, text=True, check=True).stdout)
    assert again["cache"]["template"] == "hit" and again["cache"]["shape"] == "hit"
    assert again["nodes"] == stats["nodes"] and again["tets"] == stats["tets"]
    bad = subprocess.run([os.environ["FLSH_BIN"], "avatar", "--model", "synthetic:700", "--soft",
                          "fem", "--handles", "12", "--cache", str(tmp_path)],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "only for --soft rom" in bad.stderr
    bad = subprocess.run([os.environ["FLSH_BIN"], "avatar", "--model", "synthetic:700", "--soft",
                          "xfem"], capture_output=True, text=True)
    assert bad.returncode == 2 and "--soft" in bad.stderr

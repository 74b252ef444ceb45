"""Twin-to-real calibration: known maps are recovered, bad pair sets are refused, --frame real is the map."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from tdgen.generate import generate
from tdgen.robot.calibration import CalibrationError, fit_calibration, load_calibration, read_pairs
from tdgen.robot.points_csv import read as read_points_csv

K, B = np.array([1.02, -0.98, 0.5]), np.array([12.0, -40.0, 100.0])


def _pairs(n: int, seed: int = 0, noise: float = 0.0, low=-600.0, high=600.0):
    rng = np.random.default_rng(seed)
    twin = rng.uniform(low, high, (n, 3))
    return twin, twin * K + B + rng.normal(0.0, noise, (n, 3))


def test_two_pairs_recover_scale_and_offset_per_axis():
    twin = np.array([[100.0, -200.0, 50.0], [400.0, 300.0, 350.0]])
    cal = fit_calibration(twin, twin * K + B)
    assert cal.used == "two-point"
    for axis, k, b in zip(cal.fit("two-point").axes, K, B):
        assert (axis.k, axis.b) == (pytest.approx(k), pytest.approx(b))
    np.testing.assert_allclose(cal.apply(np.array([0.0, 0.0, 0.0])), B)


def test_two_point_fit_uses_the_pairs_farthest_apart_on_each_axis():
    twin, real = _pairs(10, seed=1)
    extremes = {i for a in range(3) for i in (int(twin[:, a].argmin()), int(twin[:, a].argmax()))}
    bad = min(set(range(10)) - extremes)
    real[bad] += 25.0  # a bad middle pair: only the extremes on an axis may decide that axis
    fit = fit_calibration(twin, real, "two-point").fit("two-point")
    for a, axis in enumerate(fit.axes):
        assert axis.pairs == [int(twin[:, a].argmin()), int(twin[:, a].argmax())]
        assert (axis.k, axis.b) == (pytest.approx(K[a]), pytest.approx(B[a]))
    assert fit.residuals_mm[bad] == pytest.approx(25.0 * np.sqrt(3))


def test_many_noisy_pairs_give_scale_and_offset_by_least_squares():
    twin, real = _pairs(60, seed=2, noise=0.5)
    fit = fit_calibration(twin, real, "per-axis").fit("per-axis")
    for axis, k, b in zip(fit.axes, K, B):
        assert axis.k == pytest.approx(k, abs=2e-3) and axis.b == pytest.approx(b, abs=0.5)
    assert fit.rms_mm == pytest.approx(0.5 * np.sqrt(3), rel=0.25)


def test_an_affine_map_is_recovered_from_noisy_pairs_with_residuals_at_the_noise_level():
    rng = np.random.default_rng(3)
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    a, t = rotation * 1.05, np.array([150.0, -20.0, 75.0])
    twin = rng.uniform(-500, 500, (40, 3))
    sigma = 0.3
    real = twin @ a.T + t + rng.normal(0, sigma, twin.shape)
    cal = fit_calibration(twin, real)
    assert cal.used == "affine"
    m = np.array(cal.fit("affine").matrix)
    np.testing.assert_allclose(m[:, :3], a, atol=2e-3)
    np.testing.assert_allclose(m[:, 3], t, atol=0.5)
    residuals = np.array(cal.fit("affine").residuals_mm)
    assert len(residuals) == 40
    assert np.sqrt(np.mean(residuals ** 2)) == pytest.approx(sigma * np.sqrt(3), rel=0.3)
    assert cal.fit("per-axis").rms_mm > 10 * cal.fit("affine").rms_mm  # the rotation is beyond per-axis


def test_one_pair_is_refused_with_a_clear_message(tmp_path):
    path = tmp_path / "one.csv"
    path.write_text("twin_x,twin_y,twin_z,real_x,real_y,real_z\n1,2,3,4,5,6\n")
    with pytest.raises(CalibrationError, match="1 pair given: calibration needs at least two"):
        load_calibration(path)


def test_pairs_without_spread_on_an_axis_are_refused():
    twin = np.array([[0.0, 0.0, 5.0], [100.0, 100.0, 5.0], [200.0, 50.0, 5.0]])
    with pytest.raises(CalibrationError, match="same twin z"):
        fit_calibration(twin, twin + 1)


def test_coplanar_pairs_fall_back_from_affine_and_refuse_it_when_asked():
    twin = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 10.0], [0.0, 100.0, 20.0], [100.0, 100.0, 30.0]])
    assert fit_calibration(twin, twin * K + B).used == "per-axis"
    with pytest.raises(CalibrationError, match="one plane"):
        fit_calibration(twin, twin * K + B, "affine")


def test_pairs_csv_may_have_a_header_and_comments(tmp_path):
    path = tmp_path / "pairs.csv"
    path.write_text("twin_x,twin_y,twin_z,real_x,real_y,real_z\n# measured 2024-05-01\n0,0,0,1,2,3\n10,10,10,11,12,13\n")
    twin, real = read_pairs(path)
    assert twin.shape == real.shape == (2, 3)
    path.write_text("0,0,0,1,2,3\n10,10,10,11,12\n")
    with pytest.raises(CalibrationError, match="row 2 has 5 values"):
        read_pairs(path)


def test_real_frame_output_is_the_calibrated_transform_of_the_twin_output(tmp_path):
    twin_pts, real_pts = _pairs(8, seed=4, noise=0.0)
    pairs = tmp_path / "pairs.csv"
    np.savetxt(pairs, np.hstack([twin_pts, real_pts]), delimiter=",", fmt="%.6f")
    kwargs = dict(robot="kuka_iiwa/model.urdf", scene="table-and-wall", samples=3000, seed=5, workers=1)
    twin = generate(**kwargs, out_dir=tmp_path / "twin")
    real = generate(**kwargs, out_dir=tmp_path / "real", calibration=pairs, frame="real")
    cal = load_calibration(pairs)
    p_twin, c_twin = read_points_csv(twin.files["points"])
    p_real, c_real = read_points_csv(real.files["points"])
    np.testing.assert_array_equal(c_twin, c_real)
    np.testing.assert_allclose(p_real, cal.apply(p_twin), atol=2e-3)
    free = p_real[~c_real]
    td = real.td  # the TD the robot serves on the mesh (tm.json on disk: no base URL given)
    for i, axis in enumerate("xyz"):
        schema = td["properties"]["getCartesianposition"]["properties"][axis]
        assert (schema["minimum"], schema["maximum"]) == (pytest.approx(free[:, i].min()), pytest.approx(free[:, i].max()))
    det = abs(np.linalg.det(np.array(cal.fit(cal.used).matrix)[:, :3]))
    assert real.volume_mm3 == pytest.approx(twin.volume_mm3 * det, rel=1e-6)
    assert trimesh.load_mesh(real.files["workspace"]).volume == pytest.approx(real.volume_mm3, rel=1e-4)
    assert "real robot's frame" in td["description"]
    assert json.loads(real.files["calibration"].read_text())["used"] == cal.used


def test_the_real_frame_needs_a_calibration(tmp_path):
    with pytest.raises(CalibrationError, match="real frame needs a calibration"):
        generate("ur10.urdf", samples=10, out_dir=tmp_path, frame="real")


def test_pairs_in_different_units_are_refused_as_a_mixup_not_fitted(tmp_path):
    """A twin side in metres against a real side in mm fits a 1000x scale: a unit mixup to report."""
    twin_pts, real_pts = _pairs(8, seed=4, noise=0.0)
    pairs = tmp_path / "pairs.csv"
    np.savetxt(pairs, np.hstack([twin_pts / 1000.0, real_pts]), delimiter=",", fmt="%.6f")
    with pytest.raises(CalibrationError, match=r"scales by 1\d\d\d.*different units"):
        load_calibration(pairs)


def test_the_shipped_uarm_pairs_map_tdgens_points_to_the_real_frame(tmp_path):
    """The shipped uArm pairs are base-frame mm on both sides (the twin's model is the firmware's
    kinematics): the real-frame TD's bounds are the twin frame's, not 1000x them."""
    from tdgen.robot.model import ROBOTS_DIR

    kwargs = dict(robot="uarm_swift_pro.urdf", samples=3000, seed=1, workers=1)
    twin = generate(**kwargs, out_dir=tmp_path / "twin")
    real = generate(**kwargs, out_dir=tmp_path / "real", calibration=ROBOTS_DIR / "uarm-calibration.csv", frame="real")
    assert np.allclose(real.low_mm, twin.low_mm, atol=0.5) and np.allclose(real.high_mm, twin.high_mm, atol=0.5)
    assert 150 < real.high_mm[2] < 200  # the parallelogram keeps the tool under ~186 mm

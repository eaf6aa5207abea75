"""Pressure sensors on a body's faces (sphgraph.validation.sensors): SPHERIC test 2's box."""
import numpy as np
import pytest

from sphgraph.validation import load
from sphgraph.validation.cases import load_case
from sphgraph.validation.sensors import pressure_metrics, sensor_points

CASE = load_case("spheric2")
PRM = CASE.params
DATA, HEADER = load(CASE.reference["pressures"])


def _grid(t_end=3.0):
    dt = float(PRM["dt_sample_p"])
    return np.arange(0.0, t_end, dt)


def _as_sampled(shift=0.0, scale=1.0, t_end=3.0):
    """Each sensor's data column on the sampler's grid, delayed by `shift` s and scaled."""
    t = _grid(t_end)
    return {str(s[0]): (t, scale * np.interp(t - shift, DATA[:, 0], DATA[:, int(s[5])]))
            for s in PRM["sensors"]}


def test_the_shipped_pressures_are_the_sensors_the_case_names():
    """Eight columns at ~2 ms over 0-7.39 s; the front face's sensors see the impact bottom to top
    (P1 first, by the data's own times) and peak highest at the bottom; the top's are dry until the
    water runs over the box (after 1 s)."""
    assert DATA.shape[1] == 9 and abs(DATA[-1, 0] - 7.394) < 1e-3
    assert 0.0019 < np.median(np.diff(DATA[:, 0])) < 0.0021
    assert "doi:10.1016/j.jcp.2004.12.007" in HEADER
    first = [DATA[np.nonzero(DATA[:, c] > 2000.0)[0][0], 0] for c in (1, 2, 3, 4)]
    assert first == sorted(first) and 0.38 < first[0] < 0.41, first
    assert DATA[:, 1].max() > DATA[:, 2].max() > 1.2 * 5000
    assert all(np.abs(DATA[DATA[:, 0] < 1.0, c]).max() < 600 for c in (6, 7, 8))
    faces = [s[4] for s in PRM["sensors"]]
    assert faces == ["x+"] * 4 + ["z+"] * 4 and [int(s[5]) for s in PRM["sensors"]] == list(range(1, 9))


def test_data_against_itself_scores_zero_and_a_delay_scores_the_delay():
    m = pressure_metrics(PRM, DATA, _as_sampled(), 3.0, 1000.0)
    for s in PRM["sensors"]:
        assert m[f"p_rms_err_kPa_{s[0]}"] < 0.02          # interpolation only
    for k in ("P1", "P2", "P3", "P4"):
        assert abs(m[f"impact_t_err_s_{k}"]) <= 0.0021 and abs(m[f"first_peak_rel_err_{k}"]) < 0.02
    late = pressure_metrics(PRM, DATA, _as_sampled(shift=0.05), 3.0, 1000.0)
    for k in ("P1", "P2", "P3", "P4"):
        assert abs(late[f"impact_t_err_s_{k}"] - 0.05) <= 0.0021, late
    assert late["p_rms_err_kPa_P1"] > 10 * m["p_rms_err_kPa_P1"]
    high = pressure_metrics(PRM, DATA, _as_sampled(scale=1.2), 3.0, 1000.0)
    assert abs(high["first_peak_rel_err_P1"] - 0.2) < 0.01      # a linear filter: the ratio stays
    # the level's norm over all eight sensors, relative to rho g h0
    e = np.sqrt(np.mean([high[f"p_rms_err_kPa_{s[0]}"] ** 2 for s in PRM["sensors"]])) * 1000.0
    assert high["p_rms_err_rel_rhogh0_all"] == pytest.approx(e / (1000.0 * 9.81 * PRM["h0"]))


def test_a_sensor_that_never_sees_the_impact_reads_an_infinite_delay():
    dry = {k: (t, 0.0 * p) for k, (t, p) in _as_sampled().items()}
    m = pressure_metrics(PRM, DATA, dry, 3.0, 1000.0)
    assert m["impact_t_err_s_P1"] == np.inf and "first_peak_rel_err_P1" not in m


@pytest.mark.parametrize("dp", [0.04, 0.05])
def test_the_probes_stand_off_the_box_rows_along_each_face(dp):
    """Front sensors 2 dp in front of the box's outermost rows (+x), top sensors 2 dp above its top
    rows, the other coordinates as the experiment's; the box's rows, not the tank's floor. The box
    snaps to the lattice: its face rows lie within dp/2 of the experiment's faces."""
    from sphgraph import Scene
    from sphgraph.solver import Simulation
    sc = Scene.from_toml("examples/spheric2.toml").with_overrides(dp=dp, end_time=0.001)
    st = Simulation(sc, backend="numba-cpu").contexts[0].state
    pos, kind = st.particles.pos, st.particles.kind
    pts = dict(sensor_points(PRM, pos, kind, dp))
    box = (kind != 0) & (pos[:, 0] > 0.6) & (pos[:, 0] < 0.9) & (pos[:, 1] > 0.25) & (pos[:, 1] < 0.75) \
        & (pos[:, 2] > 0.5 * dp) & (pos[:, 2] < 0.3)
    x_face, z_top = pos[box, 0].max(), pos[box, 2].max()
    assert abs(x_face - 0.8245) <= 0.5 * dp and abs(z_top - 0.161) <= 0.5 * dp     # the lattice's nearest
    assert np.allclose(pts["P1"], [x_face + 2 * dp, 0.471, 0.021])
    assert np.allclose(pts["P8"], [0.6835, 0.471, z_top + 2 * dp])


def test_a_sensor_on_an_unknown_face_or_a_body_without_rows_is_named():
    from sphgraph.errors import InputError
    pos = np.array([[0.8, 0.5, 0.1], [0.7, 0.5, 0.16]])
    kind = np.array([1, 1])
    bad = dict(PRM, sensors=[["P1", 0.8245, 0.471, 0.021, "x", 1]])
    with pytest.raises(InputError, match=r"params.sensors\[0\]: face: expected one of x\+"):
        sensor_points(bad, pos, kind, 0.02)
    with pytest.raises(InputError, match="params.sensor_body: expected a box around boundary rows"):
        sensor_points(PRM, pos, 0 * kind, 0.02)

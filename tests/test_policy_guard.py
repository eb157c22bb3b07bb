"""A policy of one's own held to its contract: before the arm moves (check_policy: what at() returns, its offsets
against its rates, a samples file's own forces, how long a call takes) and at every tick of the run (PolicyGuard:
a fault stops the run with its data kept)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError, PolicyFault
from tactex.tasks.policies import ForceMotionPolicy, ForceRamp, PolicyLimits, PolicyPoint, SinusoidPolicy, check_policy
from tactex.tasks.policies.guard import SLACK, PolicyGuard

LIMITS = PolicyLimits(max_speed_m_s=0.15, max_accel_m_s2=2.0, min_force_n=1.0, max_force_n=20.0)
DT_S = 0.001  # the robot's tick [s]


class _Policy(ForceMotionPolicy):
    """A Python policy from a function of time (and a call count, for ones that change their mind)."""

    def __init__(self, fn, duration_s: float = 2.0) -> None:
        self.fn, self.duration_s, self.calls = fn, duration_s, 0

    def at(self, t_s: float):
        self.calls += 1
        return self.fn(t_s, self.calls)


def _still(force: float = 10.0):
    return lambda t, n: PolicyPoint(0.0, 0.0, 0.0, 0.0, force)


@pytest.mark.parametrize(("fn", "words"), [
    # the offsets swing at 0.9 m/s while the rates say the tool stands still
    (lambda t, n: PolicyPoint(0.03 * math.sin(30 * t), 0.0, 0.0, 0.0, 10.0), "offsets u, v move at 0.899 m"),
    # a 3 cm step at t = 1 s, rates zero
    (lambda t, n: PolicyPoint(0.0 if t < 1.0 else 0.03, 0.0, 0.0, 0.0, 10.0), "offsets u, v move at 7.5"),
    # slow enough, but the rates are not the path's: 5 cm/s of offset, 0 m/s said
    (lambda t, n: PolicyPoint(0.05 * t, 0.0, 0.0, 0.0, 10.0), "are not how its offsets move"),
    (lambda t, n: (0.0, 0.0, 0.0, 0.0, 10.0), "returned tuple, not a PolicyPoint"),
    (lambda t, n: PolicyPoint(0.0, math.nan, 0.0, 0.0, 10.0), "every field must be a finite number"),
    (lambda t, n: 1 / 0 if t > 0.5 else PolicyPoint(0.0, 0.0, 0.0, 0.0, 10.0), "raised ZeroDivisionError"),
    # absolute coordinates instead of offsets from the start
    (lambda t, n: PolicyPoint(0.05, 0.0, 0.0, 0.0, 10.0), "offset is u, v = 50.0, 0.0 mm"),
])
def test_the_check_refuses_what_a_python_policy_gets_wrong(fn, words) -> None:
    with pytest.raises(ConfigError, match=words):
        check_policy(_Policy(fn), LIMITS)


def test_the_check_passes_a_consistent_path_and_measures_its_calls() -> None:
    sinus = SinusoidPolicy(2.0, ForceRamp(10.0, 10.0), 0.02, 3.0, 0.01)
    call_s = check_policy(sinus, LIMITS)
    assert 0.0 < call_s < 0.01


def test_the_guard_stops_a_policy_that_changes_its_mind_after_the_check() -> None:
    """A policy checked at 12 N that asks 80 N once the run is under way, one that raises late, one that jumps."""
    cases = [
        (lambda t, n: PolicyPoint(0.0, 0.0, 0.0, 0.0, 12.0 if n < 1500 else 80.0), "force_n = 80 N left"),
        (lambda t, n: PolicyPoint(0.0, 0.0, 0.0, 0.0, 12.0) if n < 1500 else [][1], "raised IndexError"),
        (lambda t, n: PolicyPoint(0.0 if n < 1500 else 0.01, 0.0, 0.0, 0.0, 12.0), "offsets moved 10.00 mm in 1.0 ms"),
        (lambda t, n: PolicyPoint(0.0, 0.0, 0.0 if n < 1500 else 1.0, 0.0, 12.0), "rates say 1.000 m/s"),
        (lambda t, n: PolicyPoint(0.0, 0.0, 0.0, 0.0, 12.0) if n < 1500 else None, "returned NoneType"),
        # 0.2 mm back and forth every tick, rates 0: 0.2 m/s and 400 m/s² that no rate says
        (lambda t, n: PolicyPoint(0.0 if n < 1500 or n % 2 else 2e-4, 0.0, 0.0, 0.0, 12.0), "offsets moved 0.20 mm"),
        # 1.47x the speed limit, steadily, rates and offsets in agreement
        (lambda t, n: PolicyPoint(0.22 * max(t - 1.5, 0.0), 0.0, 0.22 if t > 1.5 else 0.0, 0.0, 12.0),
         "rates say 0.220 m/s"),
        # rates that jump by 0.1 m/s within a tick: an acceleration of 100 m/s²
        (lambda t, n: PolicyPoint(0.0, 0.0, 0.0 if n < 1500 else 0.1 * (n % 2), 0.0, 12.0), "rates changed by 0.100"),
        # offsets that move at 0.1 m/s while the rates say the opposite way
        (lambda t, n: PolicyPoint(0.1 * t, 0.0, 0.1 if n < 1500 else -0.1, 0.0, 12.0), "rates changed by 0.200"),
        # offsets that move at 0.1 m/s, within the limit, while the rates say the tool stands still
        (lambda t, n: PolicyPoint(0.1 * t, 0.0, 0.0, 0.0, 12.0), "while its rates said 0.000, 0.000 m/s"),
    ]
    for fn, words in cases:
        guard = PolicyGuard(_Policy(fn), LIMITS)
        with pytest.raises(PolicyFault, match=words):
            for k in range(2000):
                guard.at(k * DT_S)


def test_the_guard_lets_a_lawful_policy_run_and_allows_a_stalled_tick() -> None:
    sinus = SinusoidPolicy(math.inf, ForceRamp(10.0, 10.0), 0.02, 5.0, 0.0)  # 0.1 m/s peak, under 0.15
    guard = PolicyGuard(sinus, LIMITS)
    t = np.cumsum(np.r_[0.0, np.full(3000, DT_S), 0.006, np.full(100, DT_S)])  # a 6 ms stall of the loop
    points = [guard.at(float(x)) for x in t]
    assert points[-1] == sinus.at(float(t[-1]))
    assert guard.at(float(t[-1])) == points[-1]  # the same time again (the policy waits): no step
    # the slack is the only margin: a path at (1 + SLACK) x the limit and a little more is a fault
    fast = 1.02 * (1.0 + SLACK) * LIMITS.max_speed_m_s
    guard = PolicyGuard(_Policy(lambda t, n: PolicyPoint(fast * t, 0.0, 0.0, 0.0, 10.0)), LIMITS)
    with pytest.raises(PolicyFault, match="offsets moved"):
        for k in range(10):
            guard.at(k * DT_S)


def test_a_slow_policy_is_refused_for_a_robot_and_a_warning_in_simulation() -> None:
    from tactex.tasks.wipe_policy import POLICY_CALL_BUDGET_S, check_policy_call_time

    check_policy_call_time(0.5 * POLICY_CALL_BUDGET_S, robot=True)
    with pytest.raises(ConfigError, match="ms per call of at"):
        check_policy_call_time(5 * POLICY_CALL_BUDGET_S, robot=True)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        check_policy_call_time(5 * POLICY_CALL_BUDGET_S, robot=False)
    assert len(seen) == 1 and "ms per call of at" in str(seen[0].message)


def test_a_wipe_whose_policy_faults_mid_run_stops_with_its_data() -> None:
    """In simulation as on a robot: the run ends where the policy broke, ``aborted`` says why, the series holds
    what ran (it raised in the library before, and the run's data was lost)."""
    from tactex.tasks.wipe import WipeConfig, run_wipe

    checked = math.ceil(2.0 / 0.002) + 1  # the check's calls (every 2 ms over the run)
    policy = _Policy(lambda t, n: PolicyPoint(0.0, 0.0, 0.0, 0.0, 12.0 if n < checked + 1500 else 80.0))
    result = run_wipe(WipeConfig(duration_s=2.0), policy=policy, progress=False)
    m = result.metrics
    assert m["aborted"].startswith("PolicyFault: at t = ") and "force_n = 80 N" in m["aborted"], m["aborted"]
    assert m["partial"] is True
    assert len(result.series["t"]) > 0 and max(result.series["force_set_n"]) <= 12.0


def test_a_samples_file_with_a_bom_is_read_and_a_wrong_header_says_what_it_found(tmp_path) -> None:
    from tactex.tasks.policies import read_samples

    good = tmp_path / "excel.csv"
    good.write_text("\ufefft_s,u_m,v_m,force_n\n0,0,0,10\n1,0.01,0,10\n", encoding="utf-8")
    assert read_samples(good).shape == (2, 4)
    bad = tmp_path / "bad.csv"
    bad.write_text("time,u,v,f\n0,0,0,10\n1,0.01,0,10\n")
    with pytest.raises(InputError, match="found 'time,u,v,f'"):
        read_samples(bad)


def test_a_samples_file_force_out_of_range_is_named_by_its_own_value_and_line(tmp_path) -> None:
    from tactex.tasks.policies import SamplesPolicy, read_samples

    path = tmp_path / "drawn.csv"
    path.write_text("t_s,u_m,v_m,force_n\n0,0,0,10\n1,0.01,0,-10\n2,0.02,0,10\n")
    policy = SamplesPolicy(read_samples(path), source=str(path))
    with pytest.raises(ConfigError, match=r"line 3: force_n = -10 N is outside \[1, 20\] N"):
        check_policy(policy, LIMITS)


def test_the_live_page_of_a_policy_wipe_shows_the_policys_set_point_and_length() -> None:
    """--view with --policy: the page's set point is the policy's (it showed --force-n's), and its progress runs
    over the policy's length when that is shorter than --duration-s (it ended at 15 %)."""
    from tactex.tasks.wipe import WipeConfig, run_wipe

    class Feed:
        def __init__(self) -> None:
            self.shown: list[dict] = []

        def set_cloud(self, *args) -> None:
            pass

        def due(self) -> bool:
            return True

        def publish(self, t, **kw) -> None:
            self.shown.append(kw)

    feed = Feed()
    sinus = SinusoidPolicy(1.0, ForceRamp(12.0, 12.0), 0.01, 2.0, 0.0)
    cfg = WipeConfig(duration_s=4.0)
    assert cfg.force_n != 12.0
    run_wipe(cfg, policy=sinus, progress=False, live=feed)
    wiping = [kw for kw in feed.shown if kw["phase"] == "wipe"]
    assert wiping and {kw["set_point_n"] for kw in wiping} == {12.0}
    assert feed.shown[-1]["progress"] == pytest.approx(1.0, abs=0.01)


def test_the_sinusoids_options_beside_a_policy_file_are_said_to_be_unused(tmp_path, capsys) -> None:
    from pathlib import Path

    from tactex.cli import main

    policy = Path(__file__).resolve().parents[1] / "examples" / "policies" / "ramp_line.toml"
    code = main(["wipe", "--policy", str(policy), "--force-n", "5", "--amplitude-m", "0.01", "--duration-s", "0.3",
                 "--quiet", "--no-video", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "warning: --force-n, --amplitude-m set the built-in sinusoid" in err and "not used" in err, err


def test_a_samples_force_the_run_never_reaches_is_not_refused(tmp_path) -> None:
    from tactex.tasks.policies import SamplesPolicy, read_samples

    path = tmp_path / "long.csv"
    path.write_text("t_s,u_m,v_m,force_n\n0,0,0,10\n5,0.01,0,10\n10,0.02,0,0\n")
    policy = SamplesPolicy(read_samples(path), source=str(path))
    check_policy(policy, LIMITS, horizon_s=5.0)  # the 0 N sample at 10 s is past the run's 5 s
    with pytest.raises(ConfigError, match="line 4: force_n = 0 N"):
        check_policy(policy, LIMITS, horizon_s=10.0)


def test_the_sinusoids_force_below_the_contact_threshold_is_refused_with_the_options() -> None:
    """The run holds every policy to [contact threshold, 20 N]: the built-in sinusoid is refused before, not
    stopped after the move to the start."""
    from tactex.tasks.wipe import WipeConfig

    with pytest.raises(ConfigError, match=r"--force-n 0\.8 N is below --contact-threshold-n 1 N"):
        WipeConfig(force_n=0.8)


def test_a_policy_that_faults_at_its_first_run_time_point_stops_before_the_arm_moves(monkeypatch) -> None:
    from tactex.robots.loop import ControlLoop
    from tactex.tasks.wipe import WipeConfig, run_wipe

    moved: list = []
    for move in ("move_joints", "move_cartesian", "move_to_pose"):  # however the arm would go to the start
        monkeypatch.setattr(ControlLoop, move, lambda *args, **kw: moved.append(args))
    checked = math.ceil(2.0 / 0.002) + 1
    policy = _Policy(lambda t, n: PolicyPoint(0.0, 0.0, 0.0, 0.0, 12.0 if n <= checked else 80.0))
    with pytest.raises(PolicyFault, match="force_n = 80 N"):
        run_wipe(WipeConfig(duration_s=2.0), policy=policy, progress=False)
    assert moved == []

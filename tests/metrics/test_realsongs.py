"""The real-song benchmark's figures against hand-made joint arrays with answers worked out by hand, its song-set
builder on a generated song, and its command line end to end on a tiny checkpoint."""

import json
import math
import shutil
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import soundfile as sf

from dgsdp.benchmarks import realsongs as rs
from dgsdp.benchmarks.realsongs import songs
from dgsdp.errors import ConfigError, DgsdpError
from dgsdp.metrics.beats import motion_beats

FPS = 30


def translating(positions_x: np.ndarray, height: float = 0.5) -> np.ndarray:
    """All 24 joints at x = positions_x[t] (one point), y = 0, z = height: (T, 24, 3)."""
    joints = np.zeros((len(positions_x), 24, 3))
    joints[:, :, 0] = np.asarray(positions_x)[:, None]
    joints[:, :, 2] = height
    return joints


def test_constant_velocity_speeds():
    # 0.05 m per frame at 30 FPS is 1.5 m/s for every joint and frame
    joints = translating(0.05 * np.arange(200))
    assert rs.mean_joint_speed(joints) == pytest.approx(1.5)
    assert rs.p999_joint_speed(joints) == pytest.approx(1.5)
    np.testing.assert_allclose(rs.windowed_speed(joints), 1.5)


def test_p999_ignores_rare_spikes_but_not_sustained_ones():
    # 1000 steps x 24 joints = 24000 speeds; p99.9 sits between sorted speeds 23975 and 23976 (0-based): the 24 or
    # 25 largest count. Background: every joint at 0.5 m/s along y; spikes: joint 3 at 30 m/s.
    def dance(n_spikes: int) -> np.ndarray:
        joints = np.zeros((1001, 24, 3))
        joints[:, :, 1] = (0.5 / FPS) * np.arange(1001)[:, None]
        steps = np.zeros(1000)
        steps[100 : 100 + n_spikes] = 30.0 / FPS
        joints[1:, 3, 0] = np.cumsum(steps)  # adds 30 m/s along x: speed sqrt(30^2 + 0.5^2)
        return joints

    assert rs.p999_joint_speed(dance(10)) == pytest.approx(0.5)
    assert rs.p999_joint_speed(dance(50)) == pytest.approx(math.hypot(30.0, 0.5))


def test_penetration_cm():
    joints = translating(np.zeros(20), height=0.3)
    joints[7, 10, 2] = -0.05  # one toe 5 cm below z = 0 in one frame
    assert rs.penetration_cm(joints, 0.0) == pytest.approx(5.0)
    assert rs.penetration_cm(joints, 0.02) == pytest.approx(7.0)
    assert rs.penetration_cm(joints, -0.10) == 0.0


def test_floating_fraction_uses_the_lowest_foot_joint():
    joints = translating(np.zeros(10), height=1.0)  # the body (non-foot joints) is high everywhere
    joints[:, [7, 8, 10, 11], 2] = 0.05  # feet 5 cm up: standing
    joints[:3, [7, 8, 10, 11], 2] = 0.15  # frames 0-2: every foot joint 15 cm up: floating
    joints[5, 7, 2] = 0.6  # frame 5: one ankle lifted, the other foot down: not floating
    joints[6, 0, 2] = -0.3  # frame 6: a low pelvis does not count
    assert rs.floating_fraction(joints, 0.0) == pytest.approx(0.3)
    # the floor 10 cm higher: the raised feet are 5 cm above it, not floating
    assert rs.floating_fraction(joints, 0.10) == 0.0
    assert rs.floating_fraction(joints, -0.06) == pytest.approx(1.0)  # 0.05 + 0.06 > 0.10 everywhere


def test_window_boundaries_are_the_stride_multiples_inside_the_dance():
    np.testing.assert_array_equal(rs.window_boundaries(300, 150, 75), [75, 150, 225])
    np.testing.assert_array_equal(rs.window_boundaries(320, 150, 75), [75, 150, 225, 300])
    assert rs.window_boundaries(100, 150, 75).size == 0


def test_seam_ratio_of_smooth_and_jumping_motion():
    n, b = 300, 150
    smooth = translating((1.0 / FPS) * np.arange(n))  # 1 m/s
    assert rs.seam_ratio(smooth, [75, 150, 225]) == pytest.approx(1.0)
    # a 10 cm jump between frames 149 and 150: step 149 has speed 1 + 0.1 * 30 = 4 m/s. The +-2-frame speed of
    # frames 148..151 (whose 4 steps t-2 .. t+1 include step 149) is (3 * 1 + 4) / 4 = 1.75; every
    # other frame's is 1 (cut windows at the ends average steps of 1 m/s too). Mean over the 300 frames:
    # 1 + 4 * 0.75 / 300 = 1.01. Ratio at the one boundary 150: 1.75 / 1.01.
    jumping = translating((1.0 / FPS) * np.arange(n) + 0.1 * (np.arange(n) >= b))
    speed = rs.windowed_speed(jumping)
    np.testing.assert_allclose(speed[148:152], 1.75)
    assert speed[147] == pytest.approx(1.0) and speed[152] == pytest.approx(1.0)
    assert rs.seam_ratio(jumping, [b]) == pytest.approx(1.75 / 1.01)
    # boundaries away from the jump look like any other moment, less the jump's share of the mean
    assert rs.seam_ratio(jumping, [75, 225]) == pytest.approx(1.0 / 1.01)
    assert math.isnan(rs.seam_ratio(smooth, []))
    assert math.isnan(rs.seam_ratio(translating(np.zeros(50)), [25]))  # no motion at all


def stepping_dance(n_frames: int = 301, period: int = 20) -> np.ndarray:
    """Every joint steps along x with step 1.1 - cos(2 pi k / period): speed minima (kinematic beats) at k = 20 m."""
    k = np.arange(n_frames - 1)
    x = np.concatenate([[0.0], np.cumsum(0.01 * (1.1 - np.cos(2 * np.pi * k / period)))])
    return translating(x)


def test_bas_on_the_beat_beats_the_half_beat_shifted_copy():
    music = np.arange(20, 300, 20)  # 20 .. 280: every kinematic beat of the dance
    scores = rs.beat_scores(stepping_dance(), music)
    assert scores.shift_frames == 10
    assert scores.bas == pytest.approx(1.0)
    # shifted: every music beat is 10 frames from the nearest kinematic beat; sigma = 3 * 30 / 60 = 1.5 frames
    assert scores.shifted == pytest.approx(math.exp(-(10**2) / (2 * 1.5**2)), rel=1e-6)
    assert scores.above_shifted
    # a dance half a beat off the music: the shifted copy lands on the beats instead
    off = rs.beat_scores(stepping_dance(), music + 10)
    assert off.bas < 1e-6 and off.shifted == pytest.approx(1.0) and not off.above_shifted
    one_beat = rs.beat_scores(stepping_dance(), [40])
    assert math.isnan(one_beat.bas) and not one_beat.above_shifted


def test_bas_edge_variant_uses_the_sigmas_as_frames():
    music = np.arange(20, 300, 20)
    scores = rs.beat_scores(stepping_dance(), music, variant="bas_edge")
    assert scores.bas == pytest.approx(1.0)
    # every music beat 10 frames from the nearest shifted kinematic beat; sigma 3 frames at 30 FPS (100 ms)
    assert scores.shifted == pytest.approx(math.exp(-(10**2) / (2 * 3.0**2)), rel=1e-6)
    # smoothed with sigma 5 frames a 6-frame wobble is gone: its minima are no kinematic beats there
    wobble = translating(np.cumsum(np.r_[0.0, 0.01 * (1.1 - np.cos(2 * np.pi * np.arange(300) / 6))]))
    assert len(motion_beats(wobble, fps=30, sigma_frames=5.0)) < len(motion_beats(wobble, fps=30, sigma_frames=2.5))


def test_speed_by_phase_bins_each_step_by_its_place_in_the_beat():
    joints = stepping_dance()  # step k moves 0.3 * (1.1 - cos(2 pi k / 20)) m/s: slowest just after each beat
    beats = np.arange(20, 300, 20)
    profile = rs.speed_by_phase(joints, beats)
    speed = np.linalg.norm(np.diff(joints, axis=0), axis=-1).mean(axis=1) * FPS
    expected = np.zeros(8)
    counts = np.zeros(8)
    for k in range(len(speed)):  # step k lies at time k + 0.5; beats 20 frames apart: 2.5 frames per eighth
        t = k + 0.5
        if 20 <= t < 280:
            b = int(((t - 20) % 20) / 2.5)
            expected[b] += speed[k]
            counts[b] += 1
    np.testing.assert_allclose(profile, expected / counts, rtol=1e-12)
    assert int(np.argmin(profile)) == 0 and int(np.argmax(profile)) in (3, 4)
    assert rs.phase_bins(10, [4]).tolist() == [-1] * 10  # one beat: no phase
    assert np.isnan(rs.speed_by_phase(joints, [40])).all()
    assert rs.phase_distance(0, 7) == 1 and rs.phase_distance(2, 6) == 4 and rs.phase_distance(5, 5) == 0


def test_dance_figures_checks_follow_the_thresholds():
    joints = stepping_dance()
    joints[:, [7, 8, 10, 11], 2] = 0.0  # feet on the floor
    figures = rs.dance_figures(joints, music_beats=np.arange(20, 300, 20), boundaries=[75, 150, 225])
    assert figures.seconds == pytest.approx(301 / FPS)
    speed = figures.mean_speed_m_s
    checks = figures.checks(rs.Reference(speed))
    assert all(checks.values()) and set(checks) == {
        "p999",
        "penetration",
        "floating",
        "seam",
        "speed",
        "bas",
        "bas_edge",
    }
    # the speed target: within 30% of the training data's; without that speed it cannot pass
    for ratio, passes in ((1.29, True), (1.31, False), (0.71, True), (0.69, False)):
        assert figures.checks(rs.Reference(speed / ratio))["speed"] == passes
    assert not figures.checks(rs.Reference(math.nan))["speed"]
    joints[:, :, 2] += 0.5  # lifted 50 cm: floating in every frame
    joints[10, 3, 2] = -0.04  # and one joint 4 cm under the floor
    checks = rs.dance_figures(joints, music_beats=[20, 40, 60], boundaries=[]).checks(rs.Reference(speed))
    assert not checks["floating"] and not checks["penetration"]
    assert checks["seam"]  # one window (no boundary): no seam to check
    still = np.repeat(joints[:1], len(joints), axis=0)  # a dance that does not move: its seam ratio is NaN
    still_figures = rs.dance_figures(still, music_beats=[20, 40, 60], boundaries=[75, 150])
    assert math.isnan(still_figures.seam_ratio) and not still_figures.checks(rs.Reference(speed))["seam"]


def test_a_genre_is_judged_against_its_own_training_dances_only():
    # the training data: mean 0.5 m/s, p99.9 6.5 m/s; a fast genre (p99.9 1.25 times all's), a slow one, one with
    # too few seconds of training dances to judge by
    figures = {
        "mean_speed_m_s": 0.5,
        "p999_speed_m_s": 6.5,
        "by_genre": {
            "JS": {"mean_speed_m_s": 0.7, "p999_speed_m_s": 8.125, "seconds": 120.0},
            "WA": {"mean_speed_m_s": 0.33, "p999_speed_m_s": 2.0, "seconds": 120.0},
            "JB": {"mean_speed_m_s": 0.75, "p999_speed_m_s": 9.0, "seconds": 30.0},
        },
    }
    plain = rs.Reference.for_genre(figures, None)  # free text: all the training data
    assert rs.Reference.for_genre(figures, "BR") == plain  # a genre without training dances: the same
    assert plain.speed_range() == pytest.approx((0.35, 0.65)) and plain.p999_limit() == 8.0
    fast = rs.Reference.for_genre(figures, "JS")
    # 0.7 x 0.49 .. 1.3 x 0.7; the p99.9 limit 8 x 1.25 = 10 capped at max(8, 1.1 x 8.125) = 8.9375
    assert fast.speed_range() == pytest.approx((0.49, 0.91)) and fast.p999_limit() == pytest.approx(8.9375)
    slow = rs.Reference.for_genre(figures, "WA")
    # 0.7 x 0.33 = 0.231 is below half of all (0.25): 0.25 .. 1.3 x 0.33 = 0.429; the p99.9 limit stays 8
    assert slow.speed_range() == pytest.approx((0.25, 0.429)) and slow.p999_limit() == 8.0
    assert not slow.passes(0.65, 3.0)[1] and plain.passes(0.65, 3.0)[1]  # WA at 1.97 x WA's speed: fails now
    thin = rs.Reference.for_genre(figures, "JB")  # 30 s < 60 s: judged against all the data, and it says so
    assert thin.thin_genre == "JB" and thin.speed_range() == plain.speed_range() and thin.p999_limit() == 8.0
    assert rs.Reference.for_genre(figures, "JB", min_seconds=20.0).speed_range() == pytest.approx((0.525, 0.975))
    assert fast.overall == plain  # as set: every dance against all the training data
    # the stretch binds where the genre's p99.9 is near all's: 8 x 8.5 / 7.5 = 9.067 < max(8, 9.35)
    near = {
        "mean_speed_m_s": 0.5,
        "p999_speed_m_s": 7.5,
        "by_genre": {"KR": {"mean_speed_m_s": 0.5, "p999_speed_m_s": 8.5, "seconds": 60.0}},
    }
    assert rs.Reference.for_genre(near, "KR").p999_limit() == pytest.approx(8 * 8.5 / 7.5)  # fmt: skip
    # a JS dance moving as its genre's training dances do passes its genre's targets, not the targets as set
    assert fast.passes(0.8, 8.5) == (True, True) and plain.passes(0.8, 8.5) == (False, False)
    assert fast.passes(0.95, 9.0) == (False, False) and fast.passes(0.45, 7.0) == (True, False)  # 0.45 < 0.49
    r = rs.SongResult("x.wav", "JS", reference=fast, genre="JS")  # the summary shows both judgements
    r.figures = rs.SongFigures(10.0, 8.5, 0.0, 0.0, 1.0, 0.8, 0.5, 0.2, 0.5, 0.2, 8, 20, 3, [0.4] * 8)
    r.raw = rs.SongFigures(10.0, 9.5, 0.0, 0.0, 1.0, 0.5, 0.5, 0.2, 0.5, 0.2, 8, 20, 3, [0.4] * 8)
    r.checks, r.raw_checks = r.figures.checks(fast), r.raw.checks(fast)
    t = rs.SongResult("y.wav", "JB", reference=thin, genre="JB", error="unreadable")
    assert r.passed and rs.summary_line([r, t], 0.5).startswith("songs=2 pass=1 pass_as_set=0 errors=1 ")
    assert rs.genre_speed_line([r, t]) == (
        "speed targets by genre (the targets: a genre's dances against its own training dances, free text against "
        "all): finished speed=1/2 p999=1/2 raw speed=1/2 p999=0/2; as set (against all the training data): finished "
        "speed=0/2 p999=0/2 raw speed=1/2 p999=0/2; genres judged against all the data (under 60 s of training "
        "dances): JB"
    )
    joints = stepping_dance()
    joints[:, [7, 8, 10, 11], 2] = 0.0
    one = rs.dance_figures(joints, music_beats=np.arange(20, 300, 20), boundaries=[75, 150, 225])
    genre = {"mean_speed_m_s": one.mean_speed_m_s / 1.2, "p999_speed_m_s": 1.0, "seconds": 90.0}
    slow_data = {"mean_speed_m_s": one.mean_speed_m_s / 1.5, "p999_speed_m_s": 6.5, "by_genre": {"JS": genre}}
    assert one.checks(rs.Reference.for_genre(slow_data, "JS"))["speed"]
    assert not one.checks(rs.Reference.for_genre(slow_data, "BR"))["speed"]
    # --train-speed replaces the training data's mean (the genre's floor moves with it); without the training data
    # no speed passes, the p99.9 limit stays 8 m/s
    assert rs.Reference.for_genre(figures, "WA", 0.45).speed_range() == pytest.approx((0.231, 0.429))
    assert rs.Reference.for_genre(None, "JS").passes(0.5, 7.9) == (True, False)
    # the training dances against the targets: as set, and against their own genre's
    figures["dances"] = [
        {"genre": "JS", "mean_speed_m_s": 0.8, "p999_speed_m_s": 8.5},  # its genre's only
        {"genre": "WA", "mean_speed_m_s": 0.3, "p999_speed_m_s": 2.0},  # slower than 0.35: its genre's only
        {"genre": "WA", "mean_speed_m_s": 0.6, "p999_speed_m_s": 3.0},  # as set only: 1.8 x WA's speed
        {"genre": "BR", "mean_speed_m_s": 0.5, "p999_speed_m_s": 5.0},  # no genre figures: both as set
        {"genre": "JB", "mean_speed_m_s": 0.7, "p999_speed_m_s": 7.0},  # thin genre, too fast for all: neither
    ]
    assert rs.training_dances_passing(figures) == (2, 3, 5)
    assert rs.training_dances_passing({"mean_speed_m_s": 0.5}) == (0, 0, 0)  # a cache without the dances


def test_training_figures_without_the_training_data(tmp_path):
    figures, why = rs.training_figures(SimpleNamespace(record={"data": {"root": str(tmp_path / "gone")}}), tmp_path)
    assert figures is None and "not found" in why and "--train-speed" in why
    assert rs.training_figures(SimpleNamespace(record={}), tmp_path)[0] is None


def test_pick_varied_starts_long_and_spreads_out():
    def song(name, seconds, rms, bpm, decoder="ffmpeg"):
        return rs.SongInfo(name, name, seconds, rms, 0.0, bpm, decoder)

    songs = [
        song("a", 60, -20, 120), song("b", 61, -20, 121), song("c", 200, -18, 100), song("d", 45, -35, 90),
        song("e", 90, -10, 170), song("f", 62, -21, 119),
    ]  # fmt: skip
    picked = [s.name for s in rs.pick_varied(songs, 4)]
    assert picked[0] == "c"  # the longest
    assert len(set(picked)) == 4 and {"d", "e"} <= set(picked)  # the quiet slow one and the loud fast one
    assert len({"a", "b", "f"} & set(picked)) == 1  # one of three near-twins
    assert [s.name for s in rs.pick_varied(songs, 10)] == [s.name for s in rs.pick_varied(songs, 6)]
    assert rs.pick_varied(songs, 4) == rs.pick_varied(list(reversed(songs)), 4)
    # a rare kind of file (a tracker module, a file only the project's loader reads) comes early
    rare = [*songs, song("g.xm", 61, -20, 120), song("h.ogg", 60, -20, 121, decoder="loader")]
    assert {s.name for s in rs.pick_varied(rare, 3)[1:]} == {"g.xm", "h.ogg"}


def test_styles_cycle_per_original_song():
    songs = [Path(f"{s}.wav") for s in ("b", "b-8k", "b-96k", "b-loud", "a", "a-loud", "c")]
    assert rs.styles_for(songs, ["BR", "KR"], None) == ["KR", "KR", "KR", "KR", "BR", "BR", "BR"]
    assert rs.styles_for(songs, ["BR"], "krump") == ["krump"] * 7


def test_all_styles_dances_every_song_in_every_genre():
    songs = [Path("b.wav"), Path("b-loud.wav"), Path("a.wav")]
    pairs = rs.style_plan(songs, ["BR", "KR"], None, all_styles=True)
    assert pairs == [(songs[0], "BR"), (songs[0], "KR"), (songs[1], "BR"), (songs[1], "KR"), (songs[2], "BR"),
                     (songs[2], "KR")]  # fmt: skip
    assert rs.style_plan(songs, ["BR", "KR"], None) == list(zip(songs, ["KR", "KR", "BR"]))
    # every genre dances: those no song got dance to the original songs in turn
    assert rs.style_plan(songs, ["BR", "KR", "JS", "JB", "PO"], None) == [
        (songs[0], "KR"), (songs[1], "KR"), (songs[2], "BR"), (songs[0], "JS"), (songs[2], "JB"), (songs[0], "PO")
    ]  # fmt: skip
    with pytest.raises(ConfigError, match="leave out --style"):
        rs.style_plan(songs, ["BR"], "krump", all_styles=True)
    with pytest.raises(ConfigError, match="no genres"):
        rs.style_plan(songs, [None], None, all_styles=True)


def test_a_style_names_its_genre_by_code_or_name():
    from dgsdp.style.vocab import AISTPP_GENRES

    for style in ("KR", "gKR", "krump", "Krump"):
        assert rs.genre_of(style, AISTPP_GENRES) == "KR"
    assert rs.genre_of("Middle Hip-hop", AISTPP_GENRES) == "MH"
    for style in ("text: krump", "sharp, powerful krump with chest pops", "KR:0-10,JS:10-20", None):
        assert rs.genre_of(style, AISTPP_GENRES) is None
    assert rs.genre_of("KR", None) is None  # a model without genres


def test_tempo_line():
    from dgsdp.audio.tempo import TempoFold

    def result(name: str, style: str, speed: float, raw_speed: float, error: str | None = None) -> rs.SongResult:
        tempo = TempoFold(160.0, 1, (80.0, 135.0)) if "fast" in name else None
        r = rs.SongResult(name, style, error=error, tempo=tempo, genre=style)
        if error is None:
            r.figures = rs.SongFigures(10.0, 3.0, 0.0, 0.0, 1.0, speed, 0.5, 0.2, 0.5, 0.2, 8, 20, 3, [0.4] * 8)
            r.raw = rs.SongFigures(10.0, 3.0, 0.0, 0.0, 1.0, raw_speed, 0.5, 0.2, 0.5, 0.2, 8, 20, 3, [0.4] * 8)
        return r

    results = [
        result("a.wav", "PO", 0.38, 0.40),
        result("fast.wav", "JS", 0.50, 0.48),
        result("b.wav", "PO", 0.20, 0.25),
        result("c.wav", "BR", 0.5, 0.5),
        result("d.wav", "PO", 0.0, 0.0, error="unreadable"),
    ]
    assert rs.tempo_line(results) == (
        "tempo folds (training tempi 80-135 BPM; song BPM -> BPM given): 1 of 5 songs: fast.wav 160.0->80.0"
    )


def on_independent_beats(r: rs.SongResult, bas: float, edge: float, agree: bool = True) -> rs.SongResult:
    """``r`` with its song's beat by both trackers (agreeing or not) and BAS ``bas`` and ``edge`` against the
    independent tracker's beats (0.25 for the shifted copies), raw and finished."""
    r.tracking = rs.Tracking(120.0, 120.0 if agree else 180.0, agree, 0.9 if agree else 0.4)
    scores = {"bas": rs.BeatScores(bas, 0.25, 8, 20), "bas_edge": rs.BeatScores(edge, 0.25, 8, 20)}
    r.independent = {"raw": scores, "final": scores}
    return r


def test_raw_summary_holds_the_model_to_its_beat_target():
    def result(bas: float, edge: float, profile: list[float]) -> rs.SongResult:
        r = rs.SongResult("x.wav", "BR")
        r.raw = rs.SongFigures(10.0, 3.0, 0.0, 0.0, 1.0, 0.4, bas, 0.25, edge, 0.25, 8, 20, 3, profile)
        r.raw_checks = r.raw.checks(rs.Reference(0.4))
        r.figures, r.checks = r.raw, r.raw_checks
        return on_independent_beats(r, bas, edge)  # the same scores on the independent tracker's beats

    slow_on_beat = [0.1, 0.4, 0.6, 0.7, 0.7, 0.6, 0.4, 0.2]  # slowest in the first eighth
    train = [0.3, 0.6, 0.7, 0.8, 0.6, 0.3, 0.1, 0.05]  # slowest in the last eighth: one bin from the first
    good = [result(0.5, 0.6, slow_on_beat) for _ in range(9)]
    line, met = rs.raw_summary([*good, result(0.2, 0.6, slow_on_beat)], 0.4, train)  # 9 of 10 above: 90%
    assert met and "bas_above_shifted=9/10 bas_edge_above_shifted=10/10" in line and "low_phase=0" in line
    assert line.endswith("model_beat_target=pass") and "train_low_phase=7" in line
    assert not rs.raw_summary([*good[:8], result(0.2, 0.6, slow_on_beat)] * 1, 0.4, train)[1]  # 8 of 9
    assert not rs.raw_summary([*good, result(0.5, 0.1, slow_on_beat)][1:] + [result(0.5, 0.1, slow_on_beat)], 0.4,
                              train)[1]  # 8 of 10 in the second variant  # fmt: skip
    mid_beat = [0.5, 0.4, 0.3, 0.2, 0.1, 0.3, 0.4, 0.5]  # on the beat in both variants, slowest mid-beat
    line, met = rs.raw_summary([result(0.5, 0.6, mid_beat)] * 10, 0.4, train)
    assert not met and "low_phase=4" in line
    assert not rs.raw_summary(good, 0.4, None)[1]  # without the training dances' profile it cannot pass


def test_the_model_beat_target_needs_the_independent_beats():
    def result(name: str, on_librosa: float, on_independent: float, agree: bool = True) -> rs.SongResult:
        r = rs.SongResult(name, "BR")
        r.raw = rs.SongFigures(10.0, 3.0, 0.0, 0.0, 1.0, 0.4, on_librosa, 0.25, on_librosa, 0.25, 8, 20, 3,
                               [0.1] + [0.5] * 7)  # fmt: skip
        r.figures, r.raw_checks = r.raw, r.raw.checks(rs.Reference(0.4))
        r.checks = r.raw_checks
        return on_independent_beats(r, on_independent, on_independent, agree)

    train = [0.1] + [0.5] * 7
    # above the shifted copy on librosa's beats everywhere, on the independent beats in 5 of 10: the target fails
    half = [result(f"s{k}.wav", 0.5, 0.5 if k < 5 else 0.1) for k in range(10)]
    line, met = rs.raw_summary(half, 0.4, train)
    assert not met and "librosa_beats=pass independent_beats=FAIL model_beat_target=FAIL" in line
    assert "raw: bas_above_shifted=5/10 bas_edge_above_shifted=5/10 (librosa's beats, same dances: bas=10/10 " \
           "bas_edge=10/10) target=FAIL" in rs.independent_summary(half)  # fmt: skip
    # the 5 that miss are songs where the trackers disagree: not scored; the 5 scored pass
    for r in half[5:]:
        on_independent_beats(r, 0.1, 0.1, agree=False)
    line, met = rs.raw_summary(half, 0.4, train)
    assert met and line.endswith("librosa_beats=pass independent_beats=pass model_beat_target=pass")
    text = rs.independent_summary(half)
    assert text.startswith(
        "independent beats: the trackers agree on 5/10 songs; disagree (librosa/independent BPM, not scored): "
        "s5.wav 120/180, s6.wav 120/180, s7.wav 120/180, s8.wav 120/180, s9.wav 120/180; raw: "
        "bas_above_shifted=5/5 bas_edge_above_shifted=5/5"
    )
    for r in half:  # every song disagrees: nothing to score, the target cannot pass
        r.tracking = rs.Tracking(120.0, 180.0, False, 0.4)
    assert not rs.raw_summary(half, 0.4, train)[1]
    # a dance that errored before its song was tracked is scored, and fails
    errored = [result(f"s{k}.wav", 0.5, 0.5) for k in range(8)] + [rs.SongResult("bad.wav", "BR", error="x")]
    assert "raw: bas_above_shifted=8/9 bas_edge_above_shifted=8/9 " in rs.independent_summary(errored)
    assert not rs.raw_summary(errored, 0.4, train)[1]


def test_a_dance_that_errors_is_a_failure_in_every_count():
    def result(error: str | None = None) -> rs.SongResult:
        r = rs.SongResult("x.wav", "BR", error=error, genre="BR", reference=rs.Reference(0.4))
        if error is None:
            r.raw = rs.SongFigures(10.0, 3.0, 0.0, 0.0, 1.0, 0.4, 0.5, 0.25, 0.6, 0.25, 8, 20, 3, [0.1] + [0.5] * 7)
            r.figures, r.raw_checks = r.raw, r.raw.checks(rs.Reference(0.4))
            r.checks = r.raw_checks
            on_independent_beats(r, 0.5, 0.6)
        return r

    good, failed = [result() for _ in range(9)], [result("unreadable") for _ in range(5)]
    train = [0.1] + [0.5] * 7
    assert rs.raw_summary(good, 0.4, train)[1]  # 9 of 9: the target holds without the errors
    line, met = rs.raw_summary([*good, *failed], 0.4, train)
    assert not met and "bas_above_shifted=9/14 bas_edge_above_shifted=9/14 errors=5 " in line
    assert line.endswith("model_beat_target=FAIL")
    summary = rs.summary_line([*good, *failed], 0.4)
    assert "songs=14 pass=9 " in summary and "errors=5 " in summary
    assert "speed_within_30pct=9/14 bas_above_shifted=9/14 bas_edge_above_shifted=9/14 " in summary
    assert rs.style_summary_lines([*good, *failed])[0].startswith(
        "style=BR dances=14 pass=9 errors=5 p999_missed=5 penetration_missed=5 floating_missed=5 seam_missed=5 "
        "speed_missed=5 bas_missed=5 bas_edge_missed=5 "
    )
    assert "finished speed=9/14 p999=9/14 raw speed=9/14 p999=9/14; as set" in rs.genre_speed_line([*good, *failed])


def test_style_summary_counts_each_targets_misses_per_style():
    def result(style: str, p999: float, bas: float, error: str | None = None) -> rs.SongResult:
        r = rs.SongResult("x.wav", style, error=error, genre=style)
        if error is None:
            r.figures = rs.SongFigures(10.0, p999, 0.0, 0.0, 1.0, 0.4, bas, 0.25, bas, 0.25, 8, 20, 3, [0.4] * 8)
            r.checks = r.figures.checks(rs.Reference(0.4))
        return r

    results = [result("JS", 9.5, 0.3), result("JS", 4.0, 0.2), result("JS", 1.0, 0.0, error="unreadable"),
               result("BR", 3.0, 0.4)]  # fmt: skip
    assert rs.style_summary_lines(results) == [
        "style=JS dances=3 pass=0 errors=1 p999_missed=2 penetration_missed=1 floating_missed=1 seam_missed=1 "
        "speed_missed=1 bas_missed=2 bas_edge_missed=2 worst_p999=9.500",
        "style=BR dances=1 pass=1 errors=0 p999_missed=0 penetration_missed=0 floating_missed=0 seam_missed=0 "
        "speed_missed=0 bas_missed=0 bas_edge_missed=0 worst_p999=3.000",
    ]
    # with the training data's figures per genre, a genre's line compares its dances with that genre's own dances
    for r in results[:2]:  # JS's two finished dances (mean speed 0.4) and their raw dances (0.5 and 0.3)
        r.raw = rs.SongFigures(10.0, 1.0, 0.0, 0.0, 1.0, 0.5 if r is results[0] else 0.3, 0.3, 0.2, 0.3, 0.2, 8, 20,
                               3, [0.4] * 8)  # fmt: skip
    lines = rs.style_summary_lines(results, {"JS": {"mean_speed_m_s": 0.8, "p999_speed_m_s": 8.09, "seconds": 9.0}})
    assert lines[0].endswith(
        " worst_p999=9.500 genre_train_speed=0.800 genre_train_p999=8.09 speed_ratio_genre=0.50 "
        "raw_speed_ratio_genre=0.50"
    )
    assert "genre_train" not in lines[1]  # BR has no figures of its own here


def click_song(path: Path, seconds: float, rate_hz: int = 22050, amplitude: float = 0.3) -> None:
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    audio = amplitude * np.sin(2 * np.pi * 440 * t) * (np.mod(t, 0.5) < 0.05)  # a beep every half second
    sf.write(path, np.stack([audio, audio], axis=1), rate_hz, subtype="PCM_16")


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="the song set is built with ffmpeg")
def test_prepare_writes_four_versions_and_the_loud_one_clips(tmp_path, capsys):
    src = tmp_path / "testsongs" / "music"
    src.mkdir(parents=True)
    click_song(src / "beeps.wav", 32.0)
    click_song(src / "jingle.wav", 3.0)  # too short: a jingle, not a song
    (src / "broken.ogg").write_bytes(b"OggS not really")
    out = tmp_path / "set"
    assert rs.main(["prepare", str(out), "--sources", str(src), "--max-songs", "3"]) == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"testsongs-beeps.wav", "testsongs-beeps-loud.wav", "testsongs-beeps-8k.wav",
                     "testsongs-beeps-96k.wav", "songs.json"}  # fmt: skip
    loud, _ = sf.read(out / "testsongs-beeps-loud.wav", dtype="int16")
    original, _ = sf.read(out / "testsongs-beeps.wav", dtype="int16")
    assert np.abs(loud.astype(int)).max() >= 32767  # clipped at full scale (0.3 * 10 = 3 x full scale)
    assert np.mean(np.abs(loud.astype(int)) >= 32767) > 0.01
    assert (
        sf.info(out / "testsongs-beeps-8k.wav").samplerate == 8000
        and sf.info(out / "testsongs-beeps-8k.wav").channels == 1
    )
    assert sf.info(out / "testsongs-beeps-96k.wav").samplerate == 96000
    assert sf.info(out / "testsongs-beeps-96k.wav").duration == pytest.approx(32.0, abs=0.01)
    assert np.array_equal(original, sf.read(src / "beeps.wav", dtype="int16")[0])
    manifest = json.loads((out / "songs.json").read_text())
    assert [s["name"] for s in manifest["songs"]] == ["testsongs-beeps"]
    assert any("broken.ogg" in line for line in manifest["skipped"])
    assert manifest["songs"][0]["files"]["loud"]["peak_dbfs"] == pytest.approx(0.0, abs=0.01)
    assert "testsongs-beeps" in capsys.readouterr().out


def test_benchmark_command_end_to_end_on_a_tiny_checkpoint(tmp_path, capsys):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generation"))
    from gen_helpers import train_tiny_checkpoint, write_click_song

    checkpoint = train_tiny_checkpoint(tmp_path)
    songs = tmp_path / "songs"
    songs.mkdir()
    write_click_song(songs / "clicks.wav", 7.0, bpm=120)
    write_click_song(songs / "clicks-loud.wav", 3.0, bpm=100)
    (songs / "zz-broken.wav").write_bytes(b"RIFF not audio")
    report = tmp_path / "figures.json"
    code = rs.main([
        str(songs), "--checkpoint", checkpoint, "device=cpu", "sampling.steps=2", "progress=false",
        f"paths.cache_dir={tmp_path / 'cache'}", "--json", str(report), "--motions", str(tmp_path / "dances"),
        "sampling.tempo_range_bpm=[40,60]",  # the 120 and 100 BPM clicks are given in half time
    ])  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out.splitlines()
    data = json.loads(report.read_text())
    # each song in one genre, then the genres no song got on the original songs in turn (the broken one too)
    n_extra = len(data["songs"]) - 3
    assert printed[-5].startswith(f"songs={3 + n_extra} ") and f" errors={1 + n_extra // 2} " in printed[-5]
    first_styles = {s["style"] for s in data["songs"]}
    assert printed[-4].startswith("raw: bas_above_shifted=") and printed[-4].split()[-1] in (
        "model_beat_target=pass", "model_beat_target=FAIL"
    )  # fmt: skip
    assert printed[-3].startswith("independent beats: the trackers agree on ")
    assert printed[-3] == data["independent_beats_summary"]
    assert printed[-1].startswith("tempo folds (training tempi 40-60 BPM; song BPM -> BPM given): 2 of 3 songs: ")
    assert printed[-2].startswith("speed targets by genre (the targets: a genre's dances against its own training ")
    assert printed[-2] == data["genre_speed_summary"]
    assert any("tempo_fold=on(40-60 BPM, sampling.tempo_range_bpm);" in line for line in printed)
    assert any(line.startswith("zz-broken.wav") and "ERROR" in line for line in printed)
    assert any("sampling dpmpp_2m-2 guidance music=2 project_rotations=root " in line for line in printed)
    assert data["sampling"]["steps"] == 2 and data["sampling"]["project_rotations"] == "root"
    by_name: dict[str, dict] = {}
    for song in data["songs"]:  # a song's first dance: in its own genre
        by_name.setdefault(song["name"], song)
    assert by_name["zz-broken.wav"]["error"] and by_name["zz-broken.wav"]["figures"] is None
    long, short = by_name["clicks.wav"], by_name["clicks-loud.wav"]
    assert long["figures"]["seconds"] == pytest.approx(7.0) and short["figures"]["seconds"] == pytest.approx(3.0)
    assert long["style"] == short["style"]  # versions of one song dance in one genre
    assert long["figures"]["n_boundaries"] == 2  # 210 frames, windows of 150 frames 75 apart: 75 and 150
    assert short["figures"]["n_boundaries"] == 0 and short["figures"]["seam_ratio"] is None  # one window: no seams
    for song in (long, short):
        # the song's beat by both trackers: clicks at a steady tempo, on which they agree
        assert song["tracking"]["agree"] and song["tracking"]["independent_bpm"] == pytest.approx(
            song["tracking"]["librosa_bpm"], rel=0.04
        )
        assert set(song["independent_beats"]) == {"raw", "final"}
        assert set(song["independent_beats"]["raw"]) == {"bas", "bas_edge"}
        assert set(song["checks"]) == {"p999", "penetration", "floating", "seam", "speed", "bas", "bas_edge"}
        assert set(song["raw_checks"]) == set(song["checks"])
        assert song["figures"]["mean_speed_m_s"] > 0 and song["raw_figures"]["mean_speed_m_s"] > 0
        assert len(song["figures"]["speed_by_phase"]) == 8
        assert song["tempo"]["octaves"] == 1 and song["tempo"]["range_bpm"] == [40.0, 60.0]
        assert song["tempo"]["given_bpm"] == pytest.approx(song["tempo"]["bpm"] / 2)
        finishing = song["finishing"]  # the finishing ran, and how far it moved the joints is measured
        assert finishing["beats"] >= 2 and 0 <= finishing["anchored_beats"] <= finishing["beats"]
        assert finishing["moved_max_cm"] >= finishing["moved_mean_cm"] > 0
        assert {"tilt_limited_frames", "turn_limited_frames", "grounded_air_frames"} <= set(finishing)
    assert data["finishing"]["cleanup"] and data["finishing"]["beat_sync"]
    assert data["finishing"]["floor_cleanup"]["max_turn_rate"] == 15.0
    assert data["finishing"]["beat_sync_settings"]["max_shift_beats"] == 0.25
    assert any(line.startswith("finishing (the final rows") for line in printed)
    # the figures are those of the dance written with --motions, measured here on their own
    import torch

    from dgsdp.motion import pose_to_joints

    motion = np.load(tmp_path / "dances" / "clicks.npy")
    raw = np.load(tmp_path / "dances" / "raw" / "clicks.npy")
    assert motion.shape == raw.shape == (210, 151) and not np.allclose(motion, raw)
    raw_joints = pose_to_joints(torch.from_numpy(raw).double()).numpy()
    raw_step = np.linalg.norm(raw_joints[1:] - raw_joints[:-1], axis=-1) * 30
    assert long["raw_figures"]["mean_speed_m_s"] == pytest.approx(raw_step.mean(), rel=1e-5)
    joints = pose_to_joints(torch.from_numpy(motion).double()).numpy()
    step = np.linalg.norm(joints[1:] - joints[:-1], axis=-1) * 30
    assert long["figures"]["mean_speed_m_s"] == pytest.approx(step.mean(), rel=1e-5)
    # against the run's stored floor (the tiny dataset's measured floor height)
    from dgsdp.trained import load_model

    floor = float(load_model(checkpoint).floor_height)
    assert data["floor_m"] == pytest.approx(floor)
    depth = floor - joints[..., 2].min()
    assert long["figures"]["penetration_cm"] == pytest.approx(max(0.0, 100 * depth), rel=1e-5, abs=1e-6)
    lowest_foot = joints[:, [7, 8, 10, 11], 2].min(1)
    assert long["figures"]["floating_fraction"] == pytest.approx(np.mean(lowest_foot - floor > 0.1))
    # the training data (the tiny dataset the checkpoint was trained on) was found, measured and cached
    assert data["train_speed_m_s"] > 0 and str(tmp_path / "data") in data["train_speed_source"]
    cached = list((tmp_path / "cache" / "realsongs").glob("train-figures-*.json"))
    assert len(cached) == 1
    assert json.loads(cached[0].read_text())["figures"]["mean_speed_m_s"] == pytest.approx(data["train_speed_m_s"])
    reference = data["training_data_figures"]
    assert reference["n_dances"] == 2 and reference["seconds"] == pytest.approx(16.0)  # two 8 s dances
    assert reference["seam_ratio"] > 0  # 240 frames: boundaries at 75 and 150 laid on them
    assert long["speed_ratio"] == pytest.approx(long["figures"]["mean_speed_m_s"] / data["train_speed_m_s"])
    # per genre: every training dance counted once, and the genres' speeds, weighted by their steps (frames less
    # one per dance), average to the speed of all of them
    by_genre = reference["by_genre"]
    assert sum(g["seconds"] for g in by_genre.values()) == pytest.approx(16.0)
    from dgsdp.data.aistpp import parse_name, read_split

    genres = [parse_name(name).genre for name in read_split(tmp_path / "data", "train")]
    assert set(by_genre) == set(genres)
    steps = {genre: g["seconds"] * 30 - genres.count(genre) for genre, g in by_genre.items()}
    weighted = sum(by_genre[g]["mean_speed_m_s"] * n for g, n in steps.items()) / sum(steps.values())
    assert weighted == pytest.approx(data["train_speed_m_s"], rel=1e-9)
    # each training dance's speeds, counted against the speed targets on the training data line
    assert sorted(d["genre"] for d in reference["dances"]) == sorted(genres)
    plain, stretched, n = rs.training_dances_passing(reference)
    assert n == 2 and plain <= stretched
    counted = (
        f"; its dances within the speed and p999 targets: {plain}/2 as set, {stretched}/2 against their own genre's"
    )
    assert any(line.startswith("training data (2 dances") and line.endswith(counted) for line in printed)
    # each dance's speed limits, from its genre's figures (the tiny data's genres have 8 s of dances each: too
    # few, so they are judged against all the data and the genre line says so); the summary counts both ways
    for song in data["songs"]:
        assert song["genre"] == song["style"]  # the default run gives each dance a genre by its code
        expected = rs.Reference.for_genre(reference, song["genre"])
        assert song["limits"]["p999_speed_m_s_below"] == pytest.approx(expected.p999_limit())
        assert song["limits"]["speed_m_s_within"] == pytest.approx(list(expected.speed_range()))
        assert song["limits"]["judged_against"] == "all the training data"
        assert song["limits"]["thin_genre"] == (song["genre"] if song["genre"] in by_genre else None)
    as_set = sum(all(s["checks_as_set"].values()) for s in data["songs"] if s["figures"])
    thin = sorted({s["genre"] for s in data["songs"]} & set(by_genre))
    assert f" pass_as_set={as_set} " in printed[-5] and printed[-2].endswith(": " + (", ".join(thin) or "none"))

    # --all-styles: the one song in each of the checkpoint's genres, a row, a dance file and a summary line each
    one = tmp_path / "one"
    one.mkdir()
    write_click_song(one / "clicks.wav", 3.0, bpm=120)
    code = rs.main([
        str(one), "--checkpoint", checkpoint, "--all-styles", "device=cpu", "sampling.steps=2", "progress=false",
        f"paths.cache_dir={tmp_path / 'cache'}", "--json", str(report), "--motions", str(tmp_path / "all"),
    ])  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out.splitlines()
    data = json.loads(report.read_text())
    genres = [s["style"] for s in data["songs"]]
    assert data["all_styles"] and len(genres) >= 2 and len(set(genres)) == len(genres)
    assert first_styles == set(genres)  # the default run gave every genre a turn
    assert {p.name for p in (tmp_path / "all").iterdir() if p.is_file()} == {f"clicks__{g}.npy" for g in genres}
    summary = printed.index(next(line for line in printed if line.startswith("songs=")))
    assert printed[summary].startswith(f"songs={len(genres)} ")
    assert [line.split()[0] for line in printed[summary + 1 : -4]] == [f"style={g}" for g in genres]
    assert printed[-4].startswith("raw: ") and printed[-1].startswith("tempo folds")
    # 120 BPM: 0.26 octaves above the tiny data's 80-100 BPM, nearer than 60 BPM
    assert printed[-1] == "tempo folds (training tempi 80-100 BPM; song BPM -> BPM given): 0 of 1 songs"
    for song, line in zip(data["songs"], printed[summary + 1 : -4]):
        assert f" pass={int(song['passed'])} " in line
        genre = reference["by_genre"].get(song["style"])  # a genre with training dances: its own speed beside
        if genre is not None:
            ratio = song["figures"]["mean_speed_m_s"] / genre["mean_speed_m_s"]
            assert f" genre_train_speed={genre['mean_speed_m_s']:.3f} " in line
            assert f" speed_ratio_genre={ratio:.2f} " in line
    assert data["style_summaries"] == printed[summary + 1 : -4]
    assert any("genre_train_speed=" in line for line in data["style_summaries"])


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="the song set is built with ffmpeg")
def test_prepare_leaves_out_a_song_it_cannot_write_whole(tmp_path, monkeypatch):
    src = tmp_path / "testsongs"
    src.mkdir()
    click_song(src / "beeps.wav", 31.0)
    real_ffmpeg = songs._ffmpeg

    def failing_96k(args, out):
        if out.name.endswith("-96k.wav"):
            raise DgsdpError("ffmpeg failed writing it (simulated)")
        real_ffmpeg(args, out)

    monkeypatch.setattr(songs, "_ffmpeg", failing_96k)
    out = tmp_path / "set"
    assert rs.main(["prepare", str(out), "--sources", str(src)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["songs.json"]  # no half-written song
    manifest = json.loads((out / "songs.json").read_text())
    assert manifest["songs"] == [] and "simulated" in manifest["skipped"][0]
    assert rs.main(["prepare", str(out), "--sources", str(src)]) == 1  # a folder with files in it is refused


def test_a_model_fed_the_independent_tracker_is_checked_against_librosas(tmp_path):
    from dgsdp.audio import LibrosaEncoder
    from dgsdp.audio.beat_tracker import beats_of_song
    from dgsdp.audio.cache import FeatureCache
    from dgsdp.generation.beatsync import other_tracker_beats, song_beats

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generation"))
    from gen_helpers import write_click_song

    song = tmp_path / "clicks.wav"
    write_click_song(song, 8.0, bpm=120)
    generator = SimpleNamespace(cache=FeatureCache(tmp_path / "cache"))
    own = other_tracker_beats(song, generator.cache, LibrosaEncoder())
    assert np.array_equal(own.frames, beats_of_song(song).frames)  # the independent tracker
    swapped = other_tracker_beats(song, generator.cache, LibrosaEncoder(beat_tracker="flux"))
    assert np.array_equal(swapped.frames, song_beats(song, generator.cache, None))  # librosa's tracker
    assert swapped.bpm == pytest.approx(120, rel=0.05)

"""The blueprint is a pure function of what the session holds."""

from __future__ import annotations

from simreel.viewers.blueprint import Layout, session_blueprint


def _views(layout: Layout, tmp_path, rrd_reader) -> list[str]:
    import rerun as rr

    rec = rr.RecordingStream("simreel-test", recording_id="blueprint")
    path = tmp_path / "bp.rrd"
    rec.save(path, default_blueprint=session_blueprint(layout))
    rec.log("world/x", rr.Points3D([[0, 0, 0]]), static=True)
    rec.flush()
    rec.disconnect()
    return rrd_reader(path).blueprint_views


def test_plain_session(tmp_path, rrd_reader):
    views = _views(Layout(plot_groups=("reward", "success", "qpos")), tmp_path, rrd_reader)
    assert sorted(views) == ["3D", "TextLog", "TimeSeries", "TimeSeries"]  # task plots, joints


def test_compare_and_cameras(tmp_path, rrd_reader):
    layout = Layout(compare=True, cameras=("cameras/base_camera/rgb", "cameras/base_camera/depth"),
                    eye=(0.6, 0.7, 0.6), look_target=(0.0, 0.0, 0.2), focus=(10, 30))
    views = _views(layout, tmp_path, rrd_reader)
    assert views.count("2D") == 2 and views.count("TimeSeries") == 5  # 2 error tabs, task, joints, contacts

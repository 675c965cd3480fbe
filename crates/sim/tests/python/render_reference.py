"""Renders a MuJoCo state with Python MuJoCo's own renderer (the second path of tests/render.rs).

usage: render_reference.py STATE.json OUT.rgb

STATE.json: {"xml": path, "width": w, "height": h, "camera": name, "qpos": [...], "qvel": [...],
"mocap_pos": [...], "mocap_quat": [...], "body_pos": [...], "site_pos": [...], "time": t}
(body_pos and site_pos: the simulation's own copies of those model arrays, flattened). Writes
width x height x 3 bytes, top row first, as `mujoco.Renderer.render()` returns them.
"""
import json
import os
import sys

os.environ["MUJOCO_GL"] = "egl"
os.environ["PYOPENGL_PLATFORM"] = "egl"

import mujoco  # noqa: E402
import numpy as np  # noqa: E402


def main():
    state = json.load(open(sys.argv[1]))
    model = mujoco.MjModel.from_xml_path(state["xml"])
    model.body_pos[:] = np.asarray(state["body_pos"]).reshape(model.body_pos.shape)
    model.site_pos[:] = np.asarray(state["site_pos"]).reshape(model.site_pos.shape)
    w, h = state["width"], state["height"]
    model.vis.global_.offwidth = w
    model.vis.global_.offheight = h
    data = mujoco.MjData(model)
    data.qpos[:] = state["qpos"]
    data.qvel[:] = state["qvel"]
    data.mocap_pos[:] = np.asarray(state["mocap_pos"]).reshape(data.mocap_pos.shape)
    data.mocap_quat[:] = np.asarray(state["mocap_quat"]).reshape(data.mocap_quat.shape)
    data.time = state["time"]
    mujoco.mj_forward(model, data)
    renderer = mujoco.Renderer(model, height=h, width=w)
    renderer.update_scene(data, camera=state["camera"])
    pixels = renderer.render()
    assert pixels.shape == (h, w, 3), pixels.shape
    with open(sys.argv[2], "wb") as f:
        f.write(np.ascontiguousarray(pixels, dtype=np.uint8).tobytes())
    # Leave without closing the context: PyOpenGL's EGL teardown reports spurious errors at exit.
    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    main()

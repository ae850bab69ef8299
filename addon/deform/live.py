# SPDX-License-Identifier: GPL-3.0-or-later
"""Live playback: stepping the timeline by one frame solves that frame into the cache.

Jumping anywhere else only shows the cache as it is. Nothing runs while a
render job is active: renders evaluate their own copy of the scene and read
the cache like everything else.
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from .. import pc2
from . import bake, evaluate

_state = {"last_frame": None, "busy": False}


@persistent
def on_frame_change(scene, depsgraph=None):
    previous, frame = _state["last_frame"], scene.frame_current
    _state["last_frame"] = frame
    if _state["busy"] or previous is None or frame != previous + 1 or bpy.app.is_job_running("RENDER"):
        return
    _state["busy"] = True  # writing the cache re-evaluates the scene: no re-entry
    try:
        for obj in scene.objects:
            settings = getattr(obj, "tegument", None)
            if settings is None or not settings.live or evaluate.tegument_modifier(obj) is None:
                continue
            if not settings.frame_start <= frame <= settings.frame_end:
                continue
            if bake.is_baking(obj):
                continue  # this frame change is the bake's own stepping
            cached = pc2.frame_count(evaluate.cache_file(obj))
            if settings.frame_start + cached < frame:
                continue  # frames before this one are missing: nothing to continue from
            try:
                bake.bake_blocking(bpy.context, obj, range(frame, frame + 1), keep_existing=True, report=lambda line: None)
            except (evaluate.DeformError, pc2.CacheError) as error:
                settings.warnings = "; ".join(filter(None, (settings.bind_warnings, f"live: {error}")))
    finally:
        _state["busy"] = False


def register() -> None:
    bpy.app.handlers.frame_change_post.append(on_frame_change)


def unregister() -> None:
    if on_frame_change in bpy.app.handlers.frame_change_post:
        bpy.app.handlers.frame_change_post.remove(on_frame_change)

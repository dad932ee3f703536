"""Open a dance in Blender: import a BVH or GLB with the scene at the dance's frame rate and length, plus the song.

Run inside Blender (the file needs only Blender's Python, not the rest of the project)::

    blender --python dgsdp/export/blender_import.py -- dance.glb --audio song.wav
    blender --background --python dgsdp/export/blender_import.py -- dance.bvh --audio song.wav --save dance.blend

or, with the repository on ``sys.path`` in Blender's Python console (or with ``pip install bpy``)::

    from dgsdp.export.blender_import import import_dance
    import_dance("dance.glb", audio="song.wav")

What it does: the scene's frame rate is set to the file's (30 FPS for generated dances) before the import, so that
keyframe i lands on frame ``start + i``; the frame range becomes exactly the dance's N frames
(``start`` .. ``start + N - 1``); the song is added as a sound strip starting at ``start`` (audio and motion both
begin at the dance's first frame) and playback syncs to the audio. ``start`` is 1 for BVH (Blender's BVH importer
default) and 0 for GLB (Blender's glTF importer puts time 0 on frame 0).

BVH is imported with Blender's axes for our files (forward -Z, up Y, scale 1: metres). GLB is y-up by glTF's
definition and converted by the importer.
"""

from __future__ import annotations

import argparse
import json
import re
import struct
import sys
from dataclasses import dataclass
from pathlib import Path

GLB_MAGIC = b"glTF"
GLB_JSON_CHUNK = 0x4E4F534A


@dataclass(frozen=True)
class DanceTiming:
    """Frame count and frame rate of a dance file."""

    frames: int
    fps: float


def bvh_timing(path: str | Path) -> DanceTiming:
    """Frames and FPS from a BVH file's MOTION header (``Frames:`` and ``Frame Time:``)."""
    text = Path(path).read_text(errors="replace")
    frames = re.search(r"^\s*Frames:\s*(\d+)", text, re.MULTILINE)
    frame_time = re.search(r"^\s*Frame Time:\s*([0-9.eE+-]+)", text, re.MULTILINE)
    if not frames or not frame_time or float(frame_time.group(1)) <= 0:
        raise ValueError(f"{path} is not a BVH file with a MOTION section ('Frames:' and 'Frame Time:' lines)")
    return DanceTiming(int(frames.group(1)), round(1.0 / float(frame_time.group(1)), 6))


def glb_json(path: str | Path) -> dict:
    """The JSON chunk of a binary glTF file."""
    data = Path(path).read_bytes()
    if len(data) < 20 or data[:4] != GLB_MAGIC:
        raise ValueError(f"{path} is not a binary glTF (.glb) file")
    length, kind = struct.unpack_from("<II", data, 12)
    if kind != GLB_JSON_CHUNK:
        raise ValueError(f"{path}: the first chunk of a .glb must be JSON")
    return json.loads(data[20 : 20 + length])


def glb_timing(path: str | Path) -> DanceTiming:
    """Frames and FPS of the first animation of a .glb: from its ``extras`` (written by dgsdp), else from the
    keyframe times (count and last time) of its first sampler."""
    doc = glb_json(path)
    animations = doc.get("animations") or []
    if not animations:
        raise ValueError(f"{path} has no animation")
    extras = animations[0].get("extras") or {}
    if "frames" in extras and "fps" in extras:
        return DanceTiming(int(extras["frames"]), float(extras["fps"]))
    times = doc["accessors"][animations[0]["samplers"][0]["input"]]
    count, last = int(times["count"]), float(times["max"][0])
    if count < 2 or last <= 0:
        raise ValueError(f"{path}: cannot tell the frame rate of an animation with {count} keyframe(s)")
    return DanceTiming(count, round((count - 1) / last, 6))


def import_dance(path: str | Path, audio: str | Path | None = None, clear_scene: bool = True) -> dict:
    """Import a dance (.bvh or .glb) into the current Blender scene; see the module docstring.

    Returns a summary: ``frames``, ``fps``, ``frame_start``, ``frame_end``, ``armature`` (object name),
    ``bones``, ``sound`` (strip name or None) and ``sound_error`` (why the song could not be added: Blender builds
    without audio support, such as the ``bpy`` module from PyPI, cannot make sound strips).
    """
    import bpy  # only inside Blender

    path = Path(path).resolve()
    if not path.is_file():
        raise FileNotFoundError(f"dance file not found: {path}")
    suffix = path.suffix.lower()
    if suffix not in (".bvh", ".glb"):
        raise ValueError(f"import_dance reads .bvh or .glb files, got {path.name!r}")
    if audio is not None and not Path(audio).is_file():
        raise FileNotFoundError(f"audio file not found: {audio}")
    if clear_scene:
        bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    timing = bvh_timing(path) if suffix == ".bvh" else glb_timing(path)
    fps_int = max(1, round(timing.fps))
    scene.render.fps = fps_int
    scene.render.fps_base = 1.0 if abs(timing.fps - fps_int) < 1e-3 else fps_int / timing.fps
    before = set(bpy.data.objects)
    if suffix == ".bvh":
        start = 1
        bpy.ops.import_anim.bvh(
            filepath=str(path), global_scale=1.0, frame_start=start, axis_forward="-Z", axis_up="Y",
            update_scene_fps=False, update_scene_duration=False, rotate_mode="NATIVE",
        )  # fmt: skip
    else:
        start = 0
        bpy.ops.import_scene.gltf(filepath=str(path))
    armatures = [o for o in bpy.data.objects if o not in before and o.type == "ARMATURE"]
    if not armatures:
        raise ValueError(f"{path.name} has no skeleton Blender could import")
    scene.frame_start = start
    scene.frame_end = start + timing.frames - 1
    scene.frame_set(start)

    sound, sound_error = None, None
    if audio is not None:
        if scene.sequence_editor is None:
            scene.sequence_editor_create()
        try:
            strip = scene.sequence_editor.sequences.new_sound(
                name=Path(audio).stem, filepath=str(Path(audio).resolve()), channel=1, frame_start=start
            )
        except RuntimeError as err:  # e.g. the `bpy` module from PyPI, built without audio support (Audaspace)
            sound_error = (
                f"the song was not added: {str(err).strip()}. Add it in Blender's Video Sequencer at frame {start}."
            )
            print(f"dgsdp: {sound_error}", file=sys.stderr)
        else:
            sound = strip.name
            scene.sync_mode = "AUDIO_SYNC"
    return {
        "frames": timing.frames,
        "fps": scene.render.fps / scene.render.fps_base,
        "frame_start": scene.frame_start,
        "frame_end": scene.frame_end,
        "armature": armatures[0].name,
        "bones": len(armatures[0].data.bones),
        "sound": sound,
        "sound_error": sound_error,
    }


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``FILE [--audio SONG] [--save OUT.blend] [--report OUT.json]``, after Blender's ``--``."""
    if argv is None:
        argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    parser = argparse.ArgumentParser(prog="blender --python blender_import.py --", description=__doc__.split("\n")[0])
    parser.add_argument("file", help="a dance as .bvh or .glb")
    parser.add_argument("--audio", help="the song (wav, mp3, ...) to add as a sound strip")
    parser.add_argument("--save", help="save the scene as this .blend file")
    parser.add_argument("--report", help="write the import summary as JSON to this file")
    args = parser.parse_args(argv)
    summary = import_dance(args.file, audio=args.audio)
    if args.save:
        import bpy

        bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.save).resolve()))
    if args.report:
        Path(args.report).write_text(json.dumps(summary, indent=1))
    print(f"dgsdp: imported {summary['frames']} frames at {summary['fps']:g} FPS into frames "
          f"{summary['frame_start']}-{summary['frame_end']} ({summary['bones']} bones)")  # fmt: skip
    return summary


if __name__ == "__main__":
    main()

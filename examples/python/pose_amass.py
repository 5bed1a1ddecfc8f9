"""Poses a body through an AMASS-style motion: one PLY file per frame and a PNG sheet of a few
frames.

Usage:
    PYTHONPATH=build/python /usr/bin/python3 examples/python/pose_amass.py \
        [--model smpl.npz] [--motion amass.npz] [--out pose_amass_out]

Without --model the synthetic body is generated; without --motion the built-in "walk" is made,
saved as an AMASS-style .npz in the output folder and read back, as a real file would be.
The motion's stored betas (AMASS keeps 16) are used up to the model's number of components.
AMASS clips are z up: load_motion turns them into flsh's y-up world (the file's `up` key, else z).
"""
import argparse
import os

import numpy as np

import flsh


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", help="SMPL-format .npz (default: the synthetic body)")
    parser.add_argument("--motion", help="AMASS-style .npz (default: built-in 'walk')")
    parser.add_argument("--out", default="pose_amass_out", help="output folder")
    parser.add_argument("--max-frames", type=int, default=0, help="pose at most N frames (0 = all)")
    parser.add_argument("--sheet-frames", type=int, default=6, help="frames shown in sheet.png")
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)

    model = flsh.load_body_model(args.model) if args.model else flsh.make_synthetic_body()
    motion_path = args.motion
    if motion_path is None:
        motion_path = os.path.join(args.out, "walk.npz")
        flsh.save_motion(flsh.make_builtin_motion("walk", seconds=2.0, fps=30.0), motion_path)
    motion = flsh.load_motion(motion_path)
    frames = motion.num_frames if args.max_frames <= 0 else min(args.max_frames, motion.num_frames)
    betas = flsh.fit_betas(motion.betas, model, origin=motion.source)  # warns if it drops any
    print(f"{model}\n{motion}: posing {frames} frames")

    posed = flsh.pose_body_batch(model, betas, motion.poses[:frames], motion.trans[:frames])
    for t in range(frames):
        flsh.write_ply(os.path.join(args.out, f"frame_{t:04d}.ply"), posed.vertices[t], model.faces)

    shown = np.unique(np.linspace(0, frames - 1, max(1, args.sheet_frames)).round().astype(int))
    options = flsh.RenderOptions(width=240, height=320)
    sheet = flsh.render_sheet(posed.vertices[shown], model.faces, options)
    sheet_path = os.path.join(args.out, "sheet.png")
    flsh.write_png(sheet_path, sheet)
    print(f"wrote {frames} PLY files and {sheet_path} ({sheet.width} × {sheet.height}, "
          f"frames {', '.join(map(str, shown))}) to {args.out}")


if __name__ == "__main__":
    main()

"""``tlssim preview``: a picture of a scene seen from the scanner."""

from __future__ import annotations

import json

import scenes
from tlssim.backend import BACKENDS
from tlssim.simulate import setup_from_section


def add_parser(sub) -> None:
    p = sub.add_parser("preview", help="render a picture of a scene from the scanner (PNG)",
                       description="Render the scene from the scanner position, looking along the centre of the "
                                   "scan window (Mitsuba ray casting, light at the scanner).")
    p.add_argument("scene", help="scene file (YAML) or built-in scene name (see `tlssim scenes`)")
    p.add_argument("-o", "--output", required=True, help="output picture (.png)")
    p.add_argument("--width", type=int, default=800, help="image width in pixels (default 800)")
    p.add_argument("--backend", choices=BACKENDS, default="auto", help="ray-tracing backend")
    p.set_defaults(func=run)


def run(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import image

    from tlssim.preview import render_preview

    scene = scenes.load(args.scene)
    picture = render_preview(scene, setup_from_section(scene.scanner), width=args.width, backend=args.backend)
    image.imsave(args.output, picture)
    print(json.dumps({"output": args.output, "shape": list(picture.shape[:2]), "objects": len(scene.objects)}))
    return 0

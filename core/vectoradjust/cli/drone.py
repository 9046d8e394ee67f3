"""``vectoradjust import-images``: a folder of drone images into a project file.

``vectoradjust import-images FOLDER -o project.toml [--crs EPSG:xxxx] [--height
ellipsoidal|geoid] [--gnss-sigma H V] [--camera-json reconstruction.json] [--quiet]``
reads the images' EXIF GPS positions (and DJI's XMP gimbal angles) and camera
(:mod:`vectoradjust.files.drone`) and writes the project (``[[images]]``, ``[camera]
path`` to the camera file beside it, ``[measurements]`` to be made); control and the
road databases are added by the user before ``vectoradjust measure`` and ``adjust``.
"""

from __future__ import annotations

import argparse

from vectoradjust.cli import options

__all__ = ["add_parser", "cmd_import_images"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``import-images`` to the ``vectoradjust`` sub-parsers; its parser."""
    p = options.add_command(
        subparsers, "import-images", cmd_import_images,
        "drone images (EXIF GPS) into a project file",
        "write a project from a folder of drone images: positions from EXIF GPS, "
        "approximate attitudes, the camera from EXIF or an OpenSfM/ODM camera")
    p.add_argument("folder", help="folder of the images (JPEG or TIFF)")
    options.add_out(p, help="project file to write (TOML)")
    options.add_crs(p, help="projected CRS of the project (default: the UTM zone of the "
                            "images)")
    p.add_argument("--height", choices=("ellipsoidal", "geoid"), default=None,
                   help="what the EXIF GPS altitude is: above the WGS84 ellipsoid or above "
                        "the geoid (default: unknown, stated in the project)")
    p.add_argument("--gnss-sigma", nargs=2, type=float, default=(3.0, 5.0),
                   metavar=("H", "V"), help="GNSS sigma horizontal and vertical in m; the "
                                            "project takes the larger")
    p.add_argument("--camera-json", help="OpenSfM reconstruction.json or ODM cameras.json: a "
                                         "Brown camera instead of the EXIF one")
    options.add_quiet(p, help="print nothing but errors")
    return p


def cmd_import_images(args) -> int:
    """Run ``vectoradjust import-images``."""
    from vectoradjust.files.drone import import_images, write_drone_project

    result = import_images(args.folder, crs=args.crs, height=args.height or "unknown",
                           gnss_sigma=args.gnss_sigma, camera_json=args.camera_json)
    path = write_drone_project(result, args.out)
    if not args.quiet:
        print(f"vectoradjust import-images: {len(result.images)} images -> {path} "
              f"(camera: {path.with_name(path.stem + '_camera.toml').name})")
        for note in result.notes:
            print(f"  {note}")
    return 0

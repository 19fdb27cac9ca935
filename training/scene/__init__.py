"""Scenes: pinhole cameras (OpenCV axes), the ``Scene`` (cameras, images, masks, SfM points, split, extent), and
everything that builds one: COLMAP models, NeRF/instant-ngp ``transforms.json``, image reading and resizing, lens
undistortion, and structure from motion on a folder of photos (pycolmap).

May import ``training.core`` only.
"""

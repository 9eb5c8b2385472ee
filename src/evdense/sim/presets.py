"""The shipped scene presets: ``room``, ``desk`` and ``facade`` (scene specs, see
:mod:`evdense.sim.scene` for the format).

Each is enclosed (a textured room or backdrop box, so no ray escapes), richly textured, has light
surfaces (lamp, window, screen) and lit surfaces (``room``: the floor and the checker objects in the
window's sunlight, about 38 % of a view; ``desk``: the desk top and books under the lamp, ~33 %;
``facade``: the sunlit brick front, ~74 %, its trim, doorway and glass in shadow) whose radiance the
dataset's ``dynamic_range`` multiplies, and a smooth ~4 s path that translates the camera 1 to 4 m
from the surfaces it looks at.
World frame: metres, z up.
"""

from __future__ import annotations


def _kp(position: list[float], look_at: list[float]) -> dict:
    return {"position": position, "look_at": look_at}


def _room(
    size: list[float], wall: str = "wall", floor: str = "floor", ceiling: str = "ceiling"
) -> dict:
    """An enclosing room of ``size`` (x, y, z extents) standing on z = 0, centred on the z axis."""
    return {
        "type": "room",
        "size": size,
        "center": [0.0, 0.0, size[2] / 2],
        "material": wall,
        "face_materials": {"floor": floor, "ceiling": ceiling},
    }


def _box(size: list[float], center: list[float], material: str, **extra: object) -> dict:
    """A box object: ``size`` (x, y, z extents), ``center``, ``material``, and optional
    ``rotation_deg``, ``open_faces``, ``face_materials``."""
    return {"type": "box", "size": size, "center": center, "material": material, **extra}


def _light(low: float, tile_m: float) -> dict:
    """A light material: soft 1/f noise between ``low`` and 1, radiance 3 (times the dataset's
    dynamic range)."""
    return {
        "texture": {"type": "noise", "fmin": 1, "beta": 3.0, "low": low, "high": 1.0},
        "tile_m": tile_m,
        "radiance": 3.0,
        "light": True,
    }


def _wall(rmax: int, tile_m: float) -> dict:
    """A wall material: mottled dead leaves (radii 3 to ``rmax`` texels) on a 1024-texel texture."""
    texture = {"type": "dead_leaves", "size": 1024, "rmin": 3, "rmax": rmax, "variation": 0.3}
    return {"texture": texture, "tile_m": tile_m}


ROOM = {
    "name": "room",
    "description": "A 7 x 6 x 3 m room with five textured boxes on the floor, a poster, a bright "
    "window on the back wall and a wall lamp; the camera sweeps an arc in front of the boxes.",
    "duration": 4.0,
    "shading": {"direction": [0.3, -0.5, 1.0], "ambient": 0.55},
    "materials": {
        "wall": _wall(120, 4.0),
        "floor": {
            "texture": {"type": "noise", "size": 1024, "beta": 2.4, "low": 0.06, "high": 0.7},
            "tile_m": 4.0,
            "lit": True,  # sunlight through the window
        },
        "ceiling": {
            "texture": {"type": "noise", "beta": 2.8, "low": 0.3, "high": 0.8},
            "tile_m": 3.0,
        },
        "brick": {
            "texture": {"type": "image", "path": "skimage:brick", "repeat": 2, "variation": 0.5},
            "tile_m": 2.0,
        },
        "leaves": {"texture": {"type": "dead_leaves", "rmin": 2, "rmax": 80}, "tile_m": 0.8},
        "checker": {
            "texture": {"type": "checker", "squares": 8, "low": 0.08, "high": 0.75},
            "tile_m": 0.8,
            "lit": True,
        },
        "gravel": {"texture": "skimage:gravel", "tile_m": 0.8},
        "poster": {"texture": "skimage:astronaut", "tile_m": 1.4},
        "window": _light(0.55, 1.6),
        "lamp": _light(0.7, 0.6),
    },
    "objects": [
        _room([7.0, 6.0, 3.0]),
        _box([1.0, 0.8, 0.9], [-0.8, 1.2, 0.45], "brick", rotation_deg=[0, 0, 15]),
        _box([0.5, 0.5, 0.5], [-0.8, 1.2, 1.15], "leaves", rotation_deg=[0, 0, 40]),
        _box([0.6, 0.6, 0.6], [0.6, 1.6, 0.3], "checker", rotation_deg=[0, 0, -10]),
        _box([0.5, 0.5, 1.6], [1.8, 0.4, 0.8], "leaves", rotation_deg=[0, 0, 25]),
        _box([0.8, 0.5, 0.4], [-2.2, -0.1, 0.2], "gravel", rotation_deg=[0, 0, -20]),
        {
            "type": "cylinder",
            "center": [0.3, 0.6, 0.0],
            "radius": 0.2,
            "height": 0.7,
            "material": "checker",
        },
        {
            "type": "plane",
            "center": [0.6, 2.99, 1.7],
            "size": [1.6, 1.0],
            "normal": [0, -1, 0],
            "material": "window",
        },
        {
            "type": "plane",
            "center": [3.49, 1.2, 1.9],
            "size": [0.7, 0.45],
            "normal": [-1, 0, 0],
            "material": "lamp",
        },
        {
            "type": "plane",
            "center": [-3.49, 0.6, 1.5],
            "size": [1.4, 1.4],
            "normal": [1, 0, 0],
            "material": "poster",
        },
    ],
    "trajectory": {
        "type": "spline",
        "key_poses": [
            _kp([-1.8, -1.6, 1.5], [-0.4, 1.3, 0.8]),
            _kp([-0.6, -2.0, 1.65], [0.0, 1.4, 0.8]),
            _kp([0.7, -1.9, 1.4], [0.3, 1.3, 0.7]),
            _kp([1.8, -1.3, 1.55], [0.4, 1.4, 0.8]),
        ],
    },
}

DESK = {
    "name": "desk",
    "description": "A desk against the wall of a 5 x 4 x 2.8 m room, with a monitor (its screen a "
    "light), books, a jar, a tissue box, a desk lamp with a bright shade and a picture on the wall; "
    "the camera moves sideways 1 to 2 m in front of the desk, looking down at it.",
    "duration": 4.0,
    "shading": {"direction": [-0.4, -0.6, 1.0], "ambient": 0.5},
    "materials": {
        "wall": _wall(100, 3.0),
        "floor": {
            "texture": {"type": "image", "path": "skimage:gravel", "repeat": 4, "variation": 0.5},
            "tile_m": 4.0,
        },
        "ceiling": {
            "texture": {"type": "noise", "beta": 2.8, "low": 0.3, "high": 0.8},
            "tile_m": 2.0,
        },
        "wood": {
            "texture": {"type": "noise", "beta": 2.2, "low": 0.15, "high": 0.6},
            "tile_m": 1.0,
            "lit": True,  # the pool of the desk lamp
        },
        "plastic": {
            "texture": {"type": "noise", "beta": 2.6, "low": 0.05, "high": 0.25},
            "tile_m": 0.5,
        },
        "book1": {"texture": "skimage:text", "tile_m": 0.3, "lit": True},
        "book2": {
            "texture": {"type": "checker", "squares": 8, "low": 0.1, "high": 0.7},
            "tile_m": 0.3,
            "lit": True,
        },
        "book3": {
            "texture": {"type": "dead_leaves", "rmin": 2, "rmax": 60},
            "tile_m": 0.3,
            "lit": True,
        },
        "jar": {"texture": "skimage:coins", "tile_m": 0.4},
        "tissue": {"texture": "skimage:camera", "tile_m": 0.3},
        "picture": {"texture": "skimage:coffee", "tile_m": 0.8},
        "screen": {"texture": "skimage:astronaut", "tile_m": 0.6, "radiance": 2.0, "light": True},
        "shade": _light(0.7, 0.3),
    },
    "objects": [
        _room([5.0, 4.0, 2.8]),
        # desk: top slab on two pedestals
        {"type": "box", "size": [1.8, 0.8, 0.05], "center": [0.0, 1.55, 0.75], "material": "wood"},
        _box([0.45, 0.7, 0.725], [-0.62, 1.55, 0.3625], "wood", open_faces=["bottom"]),
        _box([0.45, 0.7, 0.725], [0.62, 1.55, 0.3625], "wood", open_faces=["bottom"]),
        # monitor: screen (front face emits), stand, foot
        _box([0.62, 0.05, 0.38], [0.1, 1.78, 1.08], "plastic", face_materials={"front": "screen"}),
        _box([0.08, 0.06, 0.14], [0.1, 1.82, 0.845], "plastic"),
        _box([0.28, 0.2, 0.02], [0.1, 1.8, 0.785], "plastic"),
        # books
        _box([0.32, 0.24, 0.05], [-0.55, 1.4, 0.8], "book1", rotation_deg=[0, 0, 8]),
        _box([0.3, 0.22, 0.05], [-0.55, 1.41, 0.85], "book2", rotation_deg=[0, 0, -6]),
        _box([0.28, 0.2, 0.06], [-0.54, 1.4, 0.905], "book3", rotation_deg=[0, 0, 14]),
        # jar and tissue box
        {
            "type": "cylinder",
            "center": [0.55, 1.35, 0.775],
            "radius": 0.08,
            "height": 0.2,
            "material": "jar",
        },
        _box([0.25, 0.13, 0.12], [-0.2, 1.3, 0.835], "tissue", rotation_deg=[0, 0, -25]),
        # desk lamp: foot, post, bright shade
        _box([0.16, 0.16, 0.03], [0.72, 1.75, 0.79], "plastic"),
        _box([0.03, 0.03, 0.36], [0.72, 1.75, 0.985], "plastic"),
        _box([0.22, 0.14, 0.1], [0.68, 1.7, 1.2], "shade", rotation_deg=[0, 0, 20]),
        # picture on the wall
        {
            "type": "plane",
            "center": [-0.5, 1.99, 1.55],
            "size": [0.8, 0.4],  # the 2:1 aspect of the cropped image (512 x 256)
            "normal": [0, -1, 0],
            "material": "picture",
        },
    ],
    "trajectory": {
        "type": "spline",
        "key_poses": [
            _kp([-0.9, 0.15, 1.4], [-0.15, 1.55, 0.9]),
            _kp([-0.3, -0.05, 1.5], [0.0, 1.55, 0.95]),
            _kp([0.35, 0.0, 1.35], [0.1, 1.55, 0.9]),
            _kp([0.95, 0.2, 1.45], [0.2, 1.55, 0.95]),
        ],
    },
}


def _facade_objects() -> list[dict]:
    objs: list[dict] = [
        # backdrop: street below, distant surroundings on the sides and behind
        _room([60.0, 60.0, 30.0], wall="surroundings", floor="street", ceiling="sky"),
        _box([16.0, 8.0, 9.5], [0.0, 4.0, 4.75], "brick", open_faces=["bottom"]),
        # door with a canopy (strong parallax) and two planters
        {
            "type": "plane",
            "center": [0.0, -0.01, 1.1],
            "size": [1.4, 2.2],
            "normal": [0, -1, 0],
            "material": "door",
        },
        _box([2.2, 1.0, 0.12], [0.0, -0.5, 2.5], "concrete"),
        _box([1.0, 0.6, 0.55], [-1.6, -0.5, 0.275], "concrete", open_faces=["bottom"]),
        _box([1.0, 0.6, 0.55], [1.6, -0.5, 0.275], "concrete", open_faces=["bottom"]),
        # pilasters at the corners of the front
        _box([0.6, 0.3, 9.5], [-6.5, -0.15, 4.75], "concrete", open_faces=["bottom"]),
        _box([0.6, 0.3, 9.5], [6.5, -0.15, 4.75], "concrete", open_faces=["bottom"]),
    ]
    lit = {(0, 1), (1, 3), (2, 0), (1, 4)}
    for row, zc in enumerate([2.0, 4.9, 7.8]):
        for col, xc in enumerate([-5.0, -2.5, 0.0, 2.5, 5.0]):
            if row == 0 and col == 2:
                continue  # the door
            mat = "lit_window" if (row, col) in lit else "glass"
            objs.append(
                {
                    "type": "plane",
                    "center": [xc, -0.01, zc],
                    "size": [1.1, 1.5],
                    "normal": [0, -1, 0],
                    "material": mat,
                }
            )
            objs.append(
                {
                    "type": "box",
                    "size": [1.4, 0.25, 0.1],
                    "center": [xc, -0.125, zc - 0.8],
                    "material": "concrete",
                }
            )
    return objs


FACADE = {
    "name": "facade",
    "description": "A 16 m wide brick building front with 14 windows (four of them lit, the lights), "
    "sills, a door under a canopy, planters and pilasters, on a street inside a backdrop box; the "
    "camera walks along the street 3 to 4.5 m from the facade, looking at it.",
    "duration": 4.0,
    "shading": {"direction": [-0.5, -1.0, 1.2], "ambient": 0.45},
    "materials": {
        "brick": {
            "texture": {"type": "image", "path": "skimage:brick", "repeat": 4, "variation": 0.6},
            "tile_m": 6.0,
            "lit": True,  # the front in the sun; trim, doorway, glass and street in shadow
        },
        "concrete": {
            "texture": {"type": "noise", "beta": 2.4, "low": 0.25, "high": 0.75},
            "tile_m": 1.0,
        },
        "door": {
            "texture": {"type": "dead_leaves", "rmin": 2, "rmax": 80, "low": 0.05, "high": 0.5},
            "tile_m": 1.0,
        },
        "glass": {
            "texture": {"type": "noise", "beta": 2.2, "low": 0.03, "high": 0.3},
            "tile_m": 1.0,
        },
        "lit_window": _light(0.5, 1.2),
        "street": {
            "texture": {"type": "image", "path": "skimage:gravel", "repeat": 4, "variation": 0.5},
            "tile_m": 6.0,
        },
        "surroundings": {"texture": {"type": "dead_leaves", "rmin": 3, "rmax": 160}, "tile_m": 8.0},
        "sky": {
            "texture": {"type": "noise", "fmin": 1, "beta": 3.0, "low": 0.6, "high": 1.0},
            "tile_m": 20.0,
            "radiance": 2.0,
        },
    },
    "objects": _facade_objects(),
    "trajectory": {
        "type": "spline",
        "key_poses": [
            _kp([-3.2, -4.3, 1.7], [-1.8, 0.0, 3.0]),
            _kp([-1.0, -3.8, 1.75], [-0.4, 0.0, 3.2]),
            _kp([1.1, -3.6, 1.65], [0.6, 0.0, 3.0]),
            _kp([3.2, -4.2, 1.7], [1.9, 0.0, 3.1]),
        ],
    },
}

PRESETS: dict[str, dict] = {"room": ROOM, "desk": DESK, "facade": FACADE}

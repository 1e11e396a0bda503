"""Material identifiers of the synthetic street and their lidar reflectivity."""

from __future__ import annotations

import numpy as np

GROUND = 0  # road, lane paint, side street and verge (decided by position)
SIDEWALK = 1  # raised concrete: top = paving slabs, sides = curb
BUILDING = 2  # walls with window grids, roof on top
POLE = 3  # metal poles and arms
LAMP = 4  # street-light head (emissive)
SIGN = 5  # sign panel (retro-reflective face)
CAR_BODY = 6  # lower body: paint, lights, plates, bumpers
CAR_CABIN = 7  # glasshouse: windows with pillars, roof
WHEEL = 8  # tyre and rim
BUS_BODY = 9  # bus: one box with window band, doors, lights
TRUNK = 10  # tree trunk
FOLIAGE = 11  # tree crown
PERSON_CLOTH = 12  # clothes of people; arms end in a hand, lower legs in a shoe (by part style)
PERSON_SKIN = 13  # head: face and hair
BIKE_FRAME = 14  # bicycle tubes, bars, saddle, cranks, pedals
BIKE_WHEEL = 15  # bicycle wheel: tyre, rim, spokes (a solid disc)

NUM_MATERIALS = 16

# Base lidar reflectivity (0..255) per material; textures refine it (lane paint, plates, lights).
BASE_REFLECTIVITY = np.array(
    [
        12.0,  # GROUND (asphalt; paint is raised in textures)
        45.0,  # SIDEWALK
        40.0,  # BUILDING
        70.0,  # POLE
        120.0,  # LAMP
        235.0,  # SIGN
        60.0,  # CAR_BODY
        30.0,  # CAR_CABIN (glass lowers it further)
        6.0,  # WHEEL
        60.0,  # BUS_BODY
        25.0,  # TRUNK
        20.0,  # FOLIAGE
        40.0,  # PERSON_CLOTH (textures scale it with the colour)
        35.0,  # PERSON_SKIN
        60.0,  # BIKE_FRAME
        8.0,  # BIKE_WHEEL
    ]
)

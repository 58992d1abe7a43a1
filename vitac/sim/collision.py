"""Contact bit masks: MuJoCo collides two geoms when (contype1 & conaffinity2) or (contype2 & conaffinity1)."""

WORLD = 1  # table and socket
PAD = 2  # tactile pads: touch only the peg
PEG = 4  # peg body against world
HAND = 8  # palm and finger links: touch only the world
PEG_GRASP = 16  # peg surface seen by the pads

WORLD_AFFINITY = PEG | HAND
PAD_AFFINITY = PEG_GRASP
PEG_AFFINITY = WORLD | PAD
HAND_AFFINITY = WORLD

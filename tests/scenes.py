"""Scene texts shared by the tests (TOML)."""

ROBOT = """[robot]
length = 0.5
youngs_modulus = 190e9
poisson_ratio = 0.3
radius = 0.001
density = 7800
"""


def two_tendon_scene(tensions: str = "[[2.0, 0.5]]", nodes: int = 20) -> str:
    """The report's rod (steel density) with tendons at +x and +y, gravity along -z."""
    return "\n" + ROBOT + f"""[[tendons]]
offset = [0.01, 0.0]
[[tendons]]
offset = [0.0, 0.01]
[loads]
gravity = [0.0, 0.0, -9.81]
[actuation]
tensions = {tensions}
[solver]
nodes = {nodes}
"""


MC_SWEEP = two_tendon_scene("[[1.0, 0.5]]", nodes=16) + """
[sweep]
chunk = 16
seed = 3
samples = 40
[[uncertainty]]
field = "robot.youngs_modulus"
distribution = "normal"
params = [190e9, 10e9]
[[uncertainty]]
field = "tendons[0].offset[0]"
distribution = "uniform"
params = [0.009, 0.011]
"""

GAIN_GRID_SWEEP = two_tendon_scene("[[0.0, 0.0]]", nodes=16) + """
[dynamics]
dt = 0.005
alpha = -0.2
steps = 100
damping_bending = [0.008, 0.008, 0.008]
[control]
target_tensions = [[1.5, 0.5]]
method = "boundary_layer"
gain_c = [20.0, 20.0, 20.0]
gain_k = [20.0, 20.0, 20.0]
epsilon = 0.005
phi = 0.001
[sweep]
chunk = 3
[sweep.grid]
"control.gain_c[0]" = [10.0, 40.0, 2]
"control.gain_k[0]" = [10.0, 40.0, 2]
"""

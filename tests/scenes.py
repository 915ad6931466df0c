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

"""Plain data: the robot (rod, tendons, loads), solver options and status bits, tip paths and
field paths. No Warp launches, no files; every field is validated here."""

"""The plant's exceptions: raised only while building (parameters, track), never inside `Plant.step`."""


class PlantConfigError(ValueError):
    """A parameter, track definition or input shape that cannot describe a physical plant."""

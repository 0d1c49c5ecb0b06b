"""The model vocabulary shared by every learner: components with declared parameters.

``Model`` (``model.py``) = ``ActionModel`` (``action.py``: features x weights; the paper's table
is the one-hot case) + ``SensorModel`` (``sensor.py``: a basis of distance) + ``InitialState``
per log (``initial.py``) + effects (``effects.py``). ``io.py`` reads and writes the model file.
"""

# The effect catalogue registers its learner twins in ``effects.EFFECT_MODELS`` on import; importing them here (the
# package's own init, run before any of its modules) fills the registry whoever imports what.
from learners.model import (  # noqa: E402,F401
    catalogue,
    catalogue_more,
    heavy_tails,
    landmark_bearing_bias,
    landmark_bias,
    turn_noise,
)

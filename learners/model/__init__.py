"""The model vocabulary shared by every learner: components with declared parameters.

``Model`` (``model.py``) = ``ActionModel`` (``action.py``: features x weights; the paper's table
is the one-hot case) + ``SensorModel`` (``sensor.py``: a basis of distance) + ``InitialState``
per log (``initial.py``) + effects (``effects.py``). ``io.py`` reads and writes the model file.
"""

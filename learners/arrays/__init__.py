"""The arrays the model and inference exchange, imported by both (and importing neither):

- ``batch``: ``Batch``, any number of logs flattened into one set of arrays (``make_batch``);
- ``lowered``: ``Lowered``, a model "lowered" to per-frame and per-sighting arrays, with the sighting model on
  them (``sighting_model``) and the sensor curve's basis (``curve``, ``fit_polynomial``);
- ``posterior``: ``Posterior``, the Gaussian beliefs an E-step returns.

``learners.model`` writes these arrays and reads posteriors; ``learners.inference`` reads the arrays and writes
posteriors; neither imports the other (``tests/test_layers.py``)."""

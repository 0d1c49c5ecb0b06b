"""aibo_core: the NumPy-only foundation shared by the simulator and the learners.

- ``trajectory``: the log format ``aibo-trajectory/2`` (``/1`` read and converted) and its I/O;
- ``npzfile``: strict ``.npz`` reading (headers checked before any data is read);
- ``atomic``: atomic file writes;
- ``geometry``: angle wrapping, the motion and observation functions with their Jacobians;
- ``actions``: the paper's table of 40 walk actions;
- ``timed_log``: a real robot's timestamped streams -> a log; its readers ``mrclam``, ``csv_import`` and
  ``rosbag_import`` (which imports ``rosbags``, the optional ``bags`` extra, only when it reads a bag); ``tum``:
  poses in the TUM trajectory format.

It imports neither gymnasium, numba, the simulator (``aibo_gym``) nor the learners.
"""

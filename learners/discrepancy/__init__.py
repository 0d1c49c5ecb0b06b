"""The discrepancy workflow: where a calibrated model and the measured data disagree, which missing
effect explains it, and how much the gap shrinks once it is added (``aibo diagnose``).

- ``split``: interleaved time blocks, so every command and every part of the field is in both halves;
- ``score``: the held-out one-step predictive log-likelihood (the gap), innovation consistency and
  whiteness;
- ``signatures``: residuals of a fit against the variables a missing effect shows up in;
- ``search``: each candidate effect fitted (warm-started), scored, tested, checked for
  identifiability; forward selection until nothing is significant.
"""

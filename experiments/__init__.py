"""Experiments: the one collect -> learn -> score loop, run over grids of specs, resumably.

The only package that knows both the simulator (``aibo_gym``) and the learners (``learners``):

* :mod:`experiments.loop`: ``simulate`` (a log from an env config and a policy spec), ``fit_em``,
  ``score`` (errors against the log's truth), ``heldout_loglik`` (an independent log of the same
  robot under the learned model);
* :mod:`experiments.run`: :class:`RunSpec` (env config, policy spec, minutes, seed, learner
  options) and ``run(spec, out_dir) -> record`` (a dict; the run's log and model kept);
* :mod:`experiments.executors`: serial, local process pool (default) and Ray backends; each record
  is written atomically as its run finishes, so an interrupted sweep resumes and loses nothing;
* :mod:`experiments.policies`: the ``aibo experiment policies`` sweep, its summary, table and plots.
"""

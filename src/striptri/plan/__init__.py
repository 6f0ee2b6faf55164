"""Pre-analysis of a planned block (issue 15, docs/plan.md): the precision and reliability the
simultaneous adjustment of a design will give, without a single measurement.

* :mod:`.design` -- the planned ground points and the noise-free measurements they predict;
* :mod:`.analysis` -- the adjustment at the plan with sigma0 = 1: a-priori mean errors, internal
  and external reliability (:func:`analyse`);
* :mod:`.whatif` -- what-ifs (drop or add control, another plate sigma) and the control ranking;
* :mod:`.report` -- report.html; :mod:`.pipeline` -- ``run_plan`` (read, analyse, write whole).
"""

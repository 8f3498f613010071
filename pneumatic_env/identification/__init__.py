"""Identification from recordings: calibration, residual diagnosis, report, virtual rig.

See docs/identification.md. Command line: ``pneumatic-env identify runs/*.csv --report
report/ [--quick]`` (:mod:`.cli`) and ``pneumatic-env rig --effect NAME --strength S --out
DIR`` (``pneumatic_env.studies.virtual_rig``). Python API (modules are imported on use):

- :func:`.calibrate.calibrate` -> :class:`.calibrate.Calibration` (``.result``, ``.save``);
  the recordings prepared in :mod:`.datasets`, the fit's statistics in :mod:`.results`
- :func:`.diagnose.diagnose` -> :class:`.diagnose.Diagnosis` (``.to_json()``): held-out
  data (:mod:`.holdout`), residual analysis (:mod:`.residuals`), screening
  (:mod:`.screening`), refits and scores (:mod:`.scoring`), progress (:mod:`.progress`)
- :func:`.report.write_report`
- :func:`.candidates.available_candidates`, :func:`.candidates.apply_sensor_model`
- :func:`.checks.read_checked`, :func:`.checks.check_recordings`
- ``pneumatic_env.studies.virtual_rig.run_rig``, ``...make_recording``,
  ``pneumatic_env.studies.rig_campaign.make_campaign``
- ``python -m pneumatic_env.studies.identification_eval [--campaign standard]``: confusion
  matrix on the virtual rig

Settings: ``configs/identification.yaml`` (:func:`.config.load_config`).
"""

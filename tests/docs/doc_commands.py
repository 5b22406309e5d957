"""Every fenced command of README.md and docs/: where the test suite runs it (at a small size), or why it
is documentation only. ``tests/docs/test_docs.py`` fails on a fenced command listed in neither, and on a listed
test that does not exist. Commands are written as the docs give them, continuation lines joined and
comments dropped."""

# ruff: noqa: E501 (a table of commands as the docs print them and the tests that run them, one per line)

#: command -> the test that runs it (or its overrides at debug size), "tests/<file>.py::<test>"
RUN = {
    "python -m encons.train model=hnn_angle system=pendulum1 debug=fast": "tests/entry/test_cli.py::test_cli_trains_quietly_and_writes_outputs",
    "python -m encons.evaluate outputs/pendulum2-hnn_angle/<timestamp>": "tests/training/test_best_checkpoint.py::test_train_and_evaluate_report_identical_metrics_of_the_best_checkpoint",
    "python -m encons.evaluate RUN data.test_steps=1000 horizon=1000": "tests/training/test_best_checkpoint.py::test_longer_test_horizon_and_whole_trajectory_score",
    "python -m encons.benchmark profile=smoke": "tests/tools/test_benchmark.py::test_smoke_profile_writes_report_and_resumes",
    "python -m encons.train -m model=node,hnn_angle system=pendulum1 debug=fast": "tests/docs/test_docs.py::test_the_readme_small_sweep_runs_both_models",
    "python -m encons.control outputs/pendulum_control-lnode/<date>": "tests/tools/test_control.py::test_control_command_scores_a_tiny_trained_run",
    "python -m encons.benchmark profile=control": "tests/tools/test_control.py::test_control_profile_reports_the_controller_beside_the_oracle",
    "python -m encons.train system=from_file system.path=rig.csv model=node 'data.recording.columns={t: time, "
    "q: [theta1, theta2], qdot: [omega1, omega2], trial: run}'": "tests/data/test_recordings.py::test_the_cli_trains_on_a_csv_recording_for_a_budget_in_steps",
    "python -m encons.data.recording example.npz": "tests/data/test_measured_data.py::test_readme_worked_example",
    "python -m encons.train system=from_file system.path=example.npz data.recording.angles=true model=glnn "
    "model.angular=true data.n_steps=50 data.test_steps=200": "tests/data/test_measured_data.py::test_readme_worked_example",
    "cd examples": "tests/extending/test_examples.py::test_the_example_system_and_model_train_through_the_cli_with_debug_fast",
    "ENCONS_TRUSTED_TARGETS='encons_examples.*' PYTHONPATH=. python -m encons.train system=duffing "
    "model=linear_newton 'hydra.searchpath=[file://conf]' debug=fast": "tests/extending/test_examples.py::test_the_example_system_and_model_train_through_the_cli_with_debug_fast",
    "ENCONS_TRUSTED_TARGETS='encons_examples.*' PYTHONPATH=. python -m encons.benchmark "
    "'hydra.searchpath=[file://conf]' 'systems=[duffing]' 'models=[linear_newton,node]' 'train=[\"debug=fast\"]'": "tests/extending/test_user_model.py::test_a_benchmarks_searchpath_reaches_every_run",
    "python -m encons.train model=node system=mass_spring regulariser=hamiltonian regulariser.weight=1e3 "
    "objective=derivative": "tests/papers/test_lim_kasim_e2e.py::test_regularised_runs_log_their_penalty",
    "python benchmarks/jacobian_speed.py --threads 1": "tests/benchmarks/test_scripts.py::test_benchmark_script_runs_at_smoke_size",
    "python benchmarks/pixel_speed.py --threads 1": "tests/benchmarks/test_scripts.py::test_benchmark_script_runs_at_smoke_size",
    "python benchmarks/symo_speed.py --threads 1": "tests/benchmarks/test_scripts.py::test_benchmark_script_runs_at_smoke_size",
    "python -m encons.train system=pixel_pendulum model=node": "tests/models/test_pixels.py::test_every_latent_model_trains_on_pixels",
    "python -m encons.train system=pixel_pendulum model=hnn": "tests/models/test_pixels.py::test_every_latent_model_trains_on_pixels",
    "python -m encons.train system=pixel_pendulum model=nsf": "tests/models/test_pixels.py::test_every_latent_model_trains_on_pixels",
    "python -m encons.train system=from_file system.path=videos.npz observation=autoencoder "
    "'observation.frame_shape=[28,28]' model=hnn": "tests/models/test_pixels.py::test_own_videos_through_from_file",
    "python -m encons.benchmark profile=xiao": "tests/tools/test_benchmark.py::test_xiao_profile_at_smoke_size_writes_tables_3_4_and_mse_curves_and_resumes",
    "python -m encons.train -m sweeps=glnn_size system=compound_pendulum data.chunk_len=500 data.batch_size=2": "tests/papers/test_xiao_size_grid.py::test_glnn_size_grid_runs_every_width_and_depth",
    "python -m encons.train model=e2e_symo system=cartpole experiment=symo_paper optimizer.lr=1e-3 model.hidden=256": "tests/docs/test_docs.py::test_symo_paper_composes_with_debug_fast_and_trains",
    "python -m encons.benchmark profile=santos": "tests/tools/test_benchmark.py::test_santos_profile_at_smoke_size_writes_figures_3_4_and_resumes",
    "python -m encons.train -m sweeps=hamiltonian_weight trainer.max_epochs=200": "tests/tools/test_sweeps.py::test_sweep_reports_its_best_trial_and_a_rerun_continues_the_study",
    "python -m encons.train -m sweeps=model_grid \"hydra.sweeper.params.seed='0,1'\"": "tests/tools/test_sweeps.py::test_model_grid_runs_every_model_and_seed",
    "python -m encons.train -m sweeps=shared_schedule && python -m encons.report multirun/shared_schedule/<date>": "tests/tools/test_sweeps.py::test_shared_schedule_trains_every_model_under_the_swept_optimiser",
    "python -m encons.train -m sweeps=hamiltonian_weight sweeps.storage=$URL sweeps.study_name=hw "
    "hydra.sweeper.sampler.seed=$K hydra.sweeper.n_trials=10": "tests/tools/test_postgres_workers.py::test_three_workers_share_one_study",
    "optuna create-study --storage $URL --study-name hw --direction minimize --skip-if-exists": "tests/tools/test_postgres_workers.py::test_three_workers_share_one_study",
    "python -m encons.sweep $URL hw report/": "tests/tools/test_postgres_workers.py::test_three_workers_share_one_study",
    "python -m encons.report benchmarks/results/quick": "tests/docs/test_readme_first_hour.py::test_the_committed_example_results_rebuild_with_the_report",
    "python -m encons.train -m sweeps=hamiltonian_weight hydra/launcher=parallel hydra.sweeper.n_jobs=4": "tests/tools/test_sweeps.py::test_launcher_configs_follow_the_sweepers_batch_size",
}

#: command -> why the suite does not run it
DOC_ONLY = {
    "make install": "builds a fresh .venv (minutes, network or a local torch wheel); CI runs it in .ci/run",
    "source .venv/bin/activate": "shell set-up, no effect to test",
    "make test-fast": "the test suite itself",
    "make lint": "CI runs it (.ci/run) before the tests",
    "python -m encons.train model=hnn_angle system=pendulum2": "full-size training (minutes); the same command at debug size is the README's first run",
    "python -m encons.train model=chnn system=gyroscope": "full-size training (minutes); chnn on the gyroscope at debug size runs in tests/training/test_train_e2e.py",
    "python -m encons.train system=from_file system.path=/data/mine.npz model=node": "a placeholder path; from_file training runs in tests/data/test_datamodule.py",
    "python -m encons.benchmark profile=lim_kasim threads=1": "the paper's protocol: hours; its report is committed",
    "python -m encons.train system=pixel_pendulum model=node regulariser=hamiltonian regulariser.weight=1.96e5": "pixel training with a regulariser: the same regulariser on latent fields runs in tests/models/test_pixels.py",
    "python -m encons.train system=pixel_damped_pendulum model=node regulariser=dissipative regulariser.weight=3.92e4": "as above, the dissipative regulariser",
    "python -m encons.benchmark profile=pixels threads=1": "the paper's protocol: hours per run; its report is committed",
    "python -m encons.train model=glnn system=damped_oscillator objective=acceleration data.chunk_len=200 "
    "data.batch_size=5 optimizer.weight_decay=0 trainer.max_epochs=300": "300 full-size epochs; glnn with the acceleration objective runs in tests/data/test_measured_data.py",
    'make benchmark ARGS="profile=quick"': "44 runs (tens of minutes); its report is committed",
    "python -m encons.benchmark profile=finzi seeds=[0] 'train=[\"trainer.max_epochs=200\"]' "
    "out=benchmarks/results/finzi-short": "four 200-epoch runs (minutes); its report is committed",
    "python -m encons.train -m sweeps=chnn_tuning system=gyroscope hydra.sweeper.n_trials=50": "50 full-size trials; the Optuna sweeper runs in tests/tools/test_sweeps.py",
    "python -m encons.train -m sweeps=optuna model=hnn 'optimizer.lr=tag(log,interval(1e-4,1e-2))' "
    "'model.hidden=choice(64,256)'": "a full-size search; the Optuna sweeper runs in tests/tools/test_sweeps.py",
    "URL=postgresql://user:pass@dbhost:5432/encons": "a placeholder server; tests/tools/test_postgres_workers.py starts one",
    "python -m encons.train -m sweeps=hamiltonian_weight sweeps.storage=$URL hydra/launcher=slurm "
    "hydra.launcher.partition=gpu hydra.launcher.gpus_per_node=1 hydra.launcher.timeout_min=120 "
    "\"hydra.launcher.setup=['source .venv/bin/activate']\" trainer=gpu hydra.sweeper.n_jobs=8": "needs a SLURM cluster; the launcher's config is checked in tests/tools/test_sweeps.py",
}

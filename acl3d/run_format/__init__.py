"""The run directory's format: what `acl3d train` writes, read back by training, campaigns and
analysis through this one package (torch-free, so analysis and campaign status stay light).

    RUN/config.yaml, config.json    the full config + derived sections, versions, command line
    RUN/provenance.json             where and with what the run was made (`documents`)
    RUN/status.json                 running | finished | interrupted | crashed (`status`)
    RUN/evals.csv                   one row per evaluation (% mastered, mean return, ...)
    RUN/evals_tasks.csv             one row per test episode (task, return, length, success)
    RUN/episodes.csv                one row per training episode (task, return, length, ...)
    RUN/teacher.json / .npz         the controller's dump (tasks, returns, teacher book-keeping)
    RUN/tb/                         TensorBoard (SB3 scalars + curriculum/* + eval/*)
    RUN/checkpoints/LATEST          name of the newest complete checkpoint folder
    RUN/checkpoints/step_N/         model.zip, model_vecnormalize.*, controller.*, runtime.*,
                                    replay_buffer.npz, rng.*, progress.json and manifest.json
                                    (every other file's size and SHA-256, `checkpoints`)
    RUN/final_model.zip (+ final_model_vecnormalize.*)

`layout` names the files, `documents` reads and writes config.yaml and provenance.json,
`status` the status, `tables` the CSV logs and `checkpoints` the checkpoint folders.
"""

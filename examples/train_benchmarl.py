"""Train MAPPO with BenchMARL on the encounter (``atc_nf_env.integrations.benchmarl``).

    python examples/train_benchmarl.py --iterations 100

Needs BenchMARL 1.5.2 and torchrl < 0.12 (``examples/requirements-benchmarl.txt``;
``make test-integrations`` builds that venv).
"""

from __future__ import annotations

import argparse
import tempfile

from benchmarl.algorithms import MappoConfig
from benchmarl.experiment import Experiment, ExperimentConfig
from benchmarl.models.mlp import MlpConfig

from atc_nf_env.integrations.benchmarl import AtcNfTask


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="converging-4")
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--frames", type=int, default=240, help="env steps per iteration")
    args = parser.parse_args(argv)

    task = AtcNfTask.ENCOUNTER.get_task(config={"scenario": args.scenario, "max_cycles": 36})
    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_iters = args.iterations
    config.max_n_frames = None
    config.on_policy_collected_frames_per_batch = args.frames
    config.on_policy_n_envs_per_worker = 1
    config.on_policy_minibatch_size = 60
    config.on_policy_n_minibatch_iters = 2
    config.evaluation = False
    config.render = False
    config.loggers = ["csv"]
    config.checkpoint_interval = 0
    config.checkpoint_at_end = False
    config.save_folder = tempfile.mkdtemp(prefix="benchmarl-")
    experiment = Experiment(
        task=task,
        algorithm_config=MappoConfig.get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=0,
        config=config,
    )
    experiment.run()
    print(f"BenchMARL MAPPO: {experiment.n_iters_performed} iterations, "
          f"{experiment.total_frames} frames; logs in {config.save_folder}", flush=True)
    return experiment.n_iters_performed


if __name__ == "__main__":
    main()

"""One mapping of config dataclasses to command-line flags (acn.flags), used by every command."""

import dataclasses

import pytest

from acn import cli
from acn.flags import config_from_args


def _config(parser, defaults, flags, argv):
    return config_from_args(parser.parse_args(argv), defaults, flags)


def test_no_option_given_builds_each_commands_config_with_the_configs_own_defaults(tmp_path):
    from acn.corrector.config import FitConfig
    from acn.diagnosis import DiagnoseConfig
    from acn.rl.ppo import PPOConfig
    from acn.sim.backends import SimConfig

    assert _config(cli.fit_parser(), FitConfig(), cli._fit_flags(), ["d", "--out", "m"]) == FitConfig()
    assert _config(cli.ppo_parser(), PPOConfig(), cli._ppo_flags(), ["--eval", "p"]) == PPOConfig()
    assert _config(cli.diagnose_parser(), DiagnoseConfig(), cli._diagnose_flags(), ["d"]) == DiagnoseConfig()
    from acn.transfer import TransferConfig

    transfer = {k: f for k, f in cli._transfer_flags().items() if k != "hidden_effects"}  # repeatable: a list
    assert _config(cli.transfer_parser(), TransferConfig(), transfer, ["--out", "x"]) == TransferConfig()
    sim = _config(cli.collect_parser(), SimConfig(), cli._sim_flags(), ["--out", "x"])
    assert all(getattr(sim, name) == getattr(SimConfig(), name) for name in cli._sim_flags())


def test_every_ppo_setting_is_an_option_parsed_to_its_fields_type():
    from acn.rl.ppo import PPOConfig

    assert set(cli._ppo_flags()) == {f.name for f in dataclasses.fields(PPOConfig)}
    argv = ["--timesteps", "64", "--out", "r", "--hidden", "64,32", "--train-reward-weights", "1,0,0.5,0",
            "--no-norm-reward", "--envs", "3", "--variant", "paper", "--log-std-init", "-0.5"]
    cfg = _config(cli.ppo_parser(), PPOConfig(), cli._ppo_flags(), argv)
    assert (cfg.hidden, cfg.train_reward_weights, cfg.norm_reward) == ((64, 32), (1.0, 0.0, 0.5, 0.0), False)
    assert (cfg.n_envs, cfg.corrector_variant, cfg.log_std_init, cfg.timesteps) == (3, "paper", -0.5, 64)


def test_a_required_field_without_a_default_is_a_required_option(capsys):
    with pytest.raises(SystemExit) as e:
        cli.import_parser().parse_args(["log.csv", "--out", "x", "--kp", "60", "--kd", "1.5", "--torque-limit", "33"])
    assert e.value.code == 2 and "--control-hz" in capsys.readouterr().err


def test_the_diagnosis_search_bound_is_an_option_where_zero_lifts_it():
    from acn.diagnosis import DiagnoseConfig

    def parsed(*argv):
        return _config(cli.diagnose_parser(), DiagnoseConfig(), cli._diagnose_flags(), ["d", *argv])

    assert (parsed("--auto-seconds", "30").auto_seconds, parsed("--auto-seconds", "0").auto_seconds) == (30.0, None)
    assert parsed("--auto-max", "2").auto_max == 2

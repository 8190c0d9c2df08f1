"""Reinforcement learning (``acn-ppo``): PPO for the A1 with the frozen corrector in the loop, the
paper's Algorithm 2. ``ppo.py`` trains and evaluates; ``policy_io.py`` saves and loads the walking
policy a user shares (``model.safetensors`` + ``config.json``, never pickle).
"""

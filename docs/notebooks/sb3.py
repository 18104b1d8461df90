# %% [markdown]
# # The envs with Stable-Baselines3
#
# `tsf/Role-v0` is a Gymnasium env of one seat with a partner in the other (any policy key, here the
# library shooter S5); Stable-Baselines3 trains on it as on any env. A short PPO run (a few thousand
# steps: a smoke run, not a trained bait; `tsf train` trains the library's), then one game of the
# result. Needs the `train` extra (`pip install -e '.[train]'`).

# %%
import gymnasium
from stable_baselines3 import PPO

from services.agent import envs  # noqa: F401  (registers tsf/Role-v0)

env = gymnasium.make("tsf/Role-v0", role="bait", partner="S5")
model = PPO("MlpPolicy", env, n_steps=512, batch_size=128, seed=0, verbose=0).learn(2048)
obs, info = env.reset(seed=1)
done, reward_sum = False, 0.0
while not done:
    obs, reward, terminated, truncated, info = env.step(model.predict(obs, deterministic=True)[0])
    reward_sum, done = reward_sum + reward, terminated or truncated
print(f"one game of the PPO bait with S5: {reward_sum:+.0f} points (the default reward: the team's points)")

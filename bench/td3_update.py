#!/usr/bin/env python3
"""One TD3 update in PyTorch (CPU), the same work as `learner::Td3::update`.

`adp bench learner --python PYTHON` runs this script right after its own measurement, with
the same thread count, and prints the ratio of the two (DESIGN §8). By hand:

    python3 bench/td3_update.py --threads 2

What one update does, as in learner/src/td3.rs (defaults of DESIGN §5):
- the batch (128 rows; obs 730, act 4) is copied from host arrays (8 pre-drawn batches,
  cycled; uniform values, every 5th row terminal, discount 0.95^6);
- target: a' = clamp(pi'(s') + clip(N(0, 0.2), +-0.5), -1, 1) with the noise drawn on the host,
  y = R + discount (1 - done) min(Q1'(s', a'), Q2'(s', a')), without gradients;
- critic step: Adam (lr 2e-5, eps 1e-8) on MSE(Q1(s, a), y) + MSE(Q2(s, a), y); the action is
  concatenated onto the observation; critics 734-512-256-1 with ReLU;
- every 2nd update (policy delay 2): actor step, Adam (lr 1e-5) on -mean Q1(s, pi(s)), actor
  730-512-512-4 with ReLU and tanh; then Polyak (tau 0.005) of the target actor and both target
  critics;
- host read-back of the critic loss, mean Q1, mean y and (on actor updates) the actor loss.

20 warm-up updates, then 200 timed; prints the mean ms/update (wall and process CPU) and the
medians of critic-only and critic+actor updates (or, with --json, one JSON object that `adp bench learner` reads).

Needs torch and numpy (PyPI's torch wheel is the CUDA build, ~5 GB installed; it runs on the
CPU). Not part of CI.
"""

import argparse
import copy
import json
import os
import statistics
import time

import numpy as np
import torch
from torch import nn

OBS, ACT, BATCH = 730, 4, 128
GAMMA, N_STEP, TAU = 0.95, 6, 0.005
TARGET_NOISE, NOISE_CLIP, POLICY_DELAY = 0.2, 0.5, 2
ACTOR_LR, CRITIC_LR, EPS = 1e-5, 2e-5, 1e-8


def mlp(sizes):
    layers = []
    for i, (a, b) in enumerate(zip(sizes, sizes[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class Actor(nn.Module):
    def __init__(self):
        super().__init__()
        self.net = mlp([OBS, 512, 512, ACT])

    def forward(self, obs):
        return torch.tanh(self.net(obs))


class TwinCritic(nn.Module):
    def __init__(self):
        super().__init__()
        self.q1 = mlp([OBS + ACT, 512, 256, 1])
        self.q2 = mlp([OBS + ACT, 512, 256, 1])

    def forward(self, obs, action):
        x = torch.cat([obs, action], 1)
        return self.q1(x), self.q2(x)

    def first(self, obs, action):
        return self.q1(torch.cat([obs, action], 1))


class Td3:
    def __init__(self):
        self.actor = Actor()
        self.critic = TwinCritic()
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=ACTOR_LR, eps=EPS)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=CRITIC_LR, eps=EPS)
        self.rng = np.random.default_rng(1)
        self.updates = 0

    def update(self, batch):
        obs, next_obs, action, reward, discount, done = (torch.from_numpy(a) for a in batch)
        noise = np.clip(self.rng.normal(0.0, TARGET_NOISE, (len(reward), ACT)), -NOISE_CLIP, NOISE_CLIP)
        with torch.no_grad():
            next_action = (self.actor_target(next_obs) + torch.from_numpy(noise.astype(np.float32))).clamp(-1.0, 1.0)
            tq1, tq2 = self.critic_target(next_obs, next_action)
            y = reward + discount * (1.0 - done) * torch.min(tq1, tq2)
        q1, q2 = self.critic(obs, action)
        critic_loss = ((q1 - y) ** 2).mean() + ((q2 - y) ** 2).mean()
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_opt.step()
        self.updates += 1
        stats = [critic_loss.item(), q1.mean().item(), y.mean().item()]
        if self.updates % POLICY_DELAY == 0:
            for p in self.critic.parameters():
                p.requires_grad_(False)
            actor_loss = -self.critic.first(obs, self.actor(obs)).mean()
            self.actor_opt.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_opt.step()
            for p in self.critic.parameters():
                p.requires_grad_(True)
            stats.append(actor_loss.item())
            with torch.no_grad():
                for target, online in ((self.actor_target, self.actor), (self.critic_target, self.critic)):
                    for t, o in zip(target.parameters(), online.parameters()):
                        t.mul_(1.0 - TAU).add_(o, alpha=TAU)
        return stats


def random_batch(rng):
    uniform = lambda *shape: rng.uniform(-1.0, 1.0, shape).astype(np.float32)  # noqa: E731
    done = (np.arange(BATCH) % 5 == 0).astype(np.float32).reshape(BATCH, 1)
    discount = np.full((BATCH, 1), GAMMA**N_STEP, dtype=np.float32)
    return uniform(BATCH, OBS), uniform(BATCH, OBS), uniform(BATCH, ACT), uniform(BATCH, 1), discount, done


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=os.cpu_count(), help="torch intra-op threads")
    parser.add_argument("--updates", type=int, default=200, help="timed updates")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a sentence")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    batches = [random_batch(rng) for _ in range(8)]
    td3 = Td3()
    for i in range(20):
        td3.update(batches[i % 8])
    critic_only, with_actor = [], []
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for i in range(args.updates):
        t = time.perf_counter()
        stats = td3.update(batches[i % 8])
        ms = (time.perf_counter() - t) * 1e3
        (with_actor if len(stats) == 4 else critic_only).append(ms)
    mean = (time.perf_counter() - wall0) * 1e3 / args.updates
    cpu = (time.process_time() - cpu0) * 1e3 / args.updates
    if args.json:
        print(
            json.dumps(
                {
                    "torch": torch.__version__,
                    "threads": torch.get_num_threads(),
                    "updates": args.updates,
                    "mean_ms": mean,
                    "critic_only_median_ms": statistics.median(critic_only),
                    "with_actor_median_ms": statistics.median(with_actor),
                }
            )
        )
        return
    print(
        f"PyTorch {torch.__version__}: TD3 update, batch {BATCH}, {OBS}/{ACT}, policy delay {POLICY_DELAY}: "
        f"mean {mean:.2f} ms/update (CPU {cpu:.2f} ms/update); median critic-only "
        f"{statistics.median(critic_only):.2f} ms, critic+actor {statistics.median(with_actor):.2f} ms "
        f"({torch.get_num_threads()} threads)"
    )


if __name__ == "__main__":
    main()

/* Drives a simulated BARN world with the ADP runtime through its C API: each control period
 * the simulated robot's scan, odometry and goal go into the navigator and its command comes
 * back into the robot. On a real robot the scan and odometry come from its drivers and the
 * command goes to its base; nothing else changes.
 *
 *   drive_world CONFIG [WORLD [SEED]]
 *
 * Prints one line with the outcome; exits 0 when the robot reached the goal. */
#include <stdio.h>
#include <stdlib.h>

#include "adp_runtime.h"

int main(int argc, char **argv) {
  if (argc < 2) {
    fprintf(stderr, "usage: %s CONFIG [WORLD [SEED]]\n", argv[0]);
    return 2;
  }
  unsigned world = argc > 2 ? (unsigned)strtoul(argv[2], NULL, 10) : 0;
  unsigned long long seed = argc > 3 ? strtoull(argv[3], NULL, 10) : 0;
  char err[512];

  AdpNavigator *nav = adp_navigator_from_file(argv[1], err, sizeof err);
  if (!nav) {
    fprintf(stderr, "navigator: %s\n", err);
    return 2;
  }
  AdpSim *sim = adp_sim_new(nav, world, seed, err, sizeof err);
  if (!sim) {
    fprintf(stderr, "sim: %s\n", err);
    adp_navigator_free(nav);
    return 2;
  }

  AdpRunStatus status = ADP_RUN_STATUS_RUNNING;
  unsigned long cycles = 0, planned = 0, agent_steps = 0, refused = 0;
  while (status == ADP_RUN_STATUS_RUNNING) {
    AdpCycleInput in;
    AdpCycleOutput out;
    adp_sim_observe(sim, &in);
    AdpStatus s = adp_navigator_cycle(nav, &in, &out, err, sizeof err);
    if (s != ADP_STATUS_OK) {
      /* out.command is a stop: issue it, and say why. */
      fprintf(stderr, "cycle %lu refused (%d): %s\n", cycles, (int)s, err);
      refused++;
    }
    cycles++;
    planned += out.planned;
    agent_steps += out.agent_step;
    status = adp_sim_step(sim, &out);
  }

  double time_s = 0.0, score = 0.0;
  adp_sim_result(sim, &time_s, &score);
  const char *how = status == ADP_RUN_STATUS_SUCCEEDED ? "succeeded"
                    : status == ADP_RUN_STATUS_COLLIDED ? "collided"
                                                        : "timed out";
  printf("world %u: %s in %.2f s, score %.3f; %lu cycles, %lu planned, %lu agent steps, "
         "%lu refused\n",
         world, how, time_s, score, cycles, planned, agent_steps, refused);
  adp_sim_free(sim);
  adp_navigator_free(nav);
  return status == ADP_RUN_STATUS_SUCCEEDED ? 0 : 1;
}

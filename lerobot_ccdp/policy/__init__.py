"""The `ccdp` policy and everything it runs at every control step: its config, the policy and its networks,
eq. (4)'s composition, the failure buffer, failure features and outcome table, the rollout memory, processors,
samplers and checkpoint checks. The lowest layer: it imports no package of lerobot_ccdp but `compat`."""

"""The `ccdp` policy: its config, the policy and its networks, processors, samplers and checkpoint checks."""

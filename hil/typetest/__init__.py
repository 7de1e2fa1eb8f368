"""Type tests: programmes of lockstep runs judged by metrics from plant truth (the WSP test, `railhil
wsp-test`)."""

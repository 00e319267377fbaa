"""Fault injection into real runs: services SIGKILLed (`service_kills`), network faults between
hosts in network namespaces (`net_faults`, `netns`, `delay_relay`, `rejoin`, `stranded_gets`),
the chaos soak (`chaos*`) and a killed replay's recovery time (`replay_recovery`), each run as
`python -m bench.faults.<name>`; docs/FAULTS.md collects what they showed.
"""

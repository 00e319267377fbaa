"""hercs' methods inside other libraries' training loops (`hercs.integrations.sb3`,
`hercs.integrations.torchrl`): each a thin shim over `clustered_episodes`, which drives the
replay's own samplers and the clusterer's core."""

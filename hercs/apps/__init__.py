"""The applications on top of the library and the services: the `hercs` command (cli),
`hercs up` (launcher), the router, the offline and live Rerun views and the plots."""

"""The WoT HTTP adapter: every Thing of the mesh as a standard WoT HTTP Thing (SPEC §5).

Layout after node-wot's binding-http: routes grouped by affordance kind (`properties`, `actions`,
`events`, `things` for TDs, directory and files), `tdrewrite` for HTTP forms, `gateway` for the
adapter's view of the mesh, `problems` for the one Problem-to-HTTP mapping, `auth`, `app`
(the Starlette factory) and `server` (the process entry, `run`).
"""

"""What the tests, the benchmarks and tools/ share to run the product on the fakes.

``config``: the ritad config template (one function, ``@TMP@`` placeholders that
``fakes.launch.start_ritad`` fills in); ``browser``: the console in headless chromium.
Neither product nor simulation, so neither under daemon/ nor under fakes/; not under
tests/ either, so that bench/ and tools/ import nothing from the tests.
"""

"""``nearlight site``: a static HTML site of results folders, reports and scorecards (docs/results-site.md).

:mod:`.leaderboard` turns scorecards into a suite's rows (each number with the JSON pointer it came from),
:mod:`.pages` turns a report's Markdown into a page (its links and images made to resolve inside the site),
:mod:`.build` finds the inputs, writes the site and keeps the output-place rule, :mod:`.cli` is the verb.
"""

"""The LaTeX of the bench's tables (compensation.reports.tables.latex_table), checked without a LaTeX
installation: balanced braces, one of each booktabs rule, every row as wide as the header, every
special character escaped and the Unicode of the labels in math mode. The bench tests check the
files a bench writes with :func:`latex_problems`."""
from __future__ import annotations

import re

from compensation.reports.tables import latex_table

SPECIAL = "&%$#_{}~^\\"
"""The characters LaTeX reads as commands; each must be escaped."""


def latex_problems(tex: str, columns: int) -> list[str]:
    """What makes ``tex`` (a table of :func:`~compensation.reports.tables.latex_table`) invalid, found
    without LaTeX: unbalanced braces, not one of each booktabs rule, rows of another width than
    ``columns``, a special character or a non-ASCII one left raw outside math mode."""
    problems = []
    lines = tex.splitlines()
    body = [line for line in lines if not line.startswith("%")]  # the comment line names the package
    text = "\n".join(body)
    unescaped = re.sub(r"\\[&%$#_{}]", "", text)  # escaped characters are text
    depth = 0
    for char in unescaped:
        depth += {"{": 1, "}": -1}.get(char, 0)
        if depth < 0:
            problems.append("a } closes nothing")
    if depth:
        problems.append(f"{depth} unclosed {{")
    found = {rule: text.count(rule) for rule in (r"\toprule", r"\midrule", r"\bottomrule")}
    problems += [f"{rule} {n} times, not once" for rule, n in found.items() if n != 1]
    ok = set(found.values()) == {1}
    rows = lines[lines.index(r"\toprule") + 1:lines.index(r"\bottomrule")] if ok else []
    for line in rows:
        if line == r"\midrule":
            continue
        if not line.endswith(r" \\"):
            problems.append(f"row without its end: {line}")
        cells = re.sub(r"\\[&%$#_{}]", "", line).count("&") + 1
        if cells != columns:
            problems.append(f"{cells} cells, not {columns}: {line}")
    for line in body:
        plain = re.sub(r"\\[&%$#_{}]|\\text(backslash|asciitilde|asciicircum)\{\}", "", line)
        if plain.count("$") % 2:
            problems.append(f"unbalanced $: {line}")
        outside_math = re.sub(r"\$[^$]*\$", "", plain)
        # what is left: commands (a backslash and letters), their braces, the row end and separators
        text_only = re.sub(r"\\[a-zA-Z]+|\\\\$|[{}]| & ", "", outside_math)
        problems += [f"raw {c!r}: {line}" for c in SPECIAL if c in text_only]
    problems += [f"not ASCII: {c!r}" for c in sorted(set(tex)) if ord(c) > 127]
    return problems


def test_latex_of_every_special_and_unicode_character():
    header = ["method", "n_train", "PSNR"]
    rows = [["a&b %c $d #e_f {g} ~h ^i \\j", 8, 20.123456],
            ["tps (λ = 0.0347·α²), π†(x̃) − 1 → ΔE ≤ ℓ", "-", float("nan")]]
    tex = latex_table("Title & 50 % of 64² px_1", header, rows, "note: $5 #1 ~ ^ \\ {x}\n\nsecond paragraph")
    assert latex_problems(tex, 3) == []
    assert r"\begin{tabular}{lrr}" in tex and r"\caption{Title \& 50 \% of 64$^{2}$ px\_1}" in tex
    assert (r"a\&b \%c \$d \#e\_f \{g\} \textasciitilde{}h \textasciicircum{}i \textbackslash{}j & 8 & "
            r"20.1235 \\") in tex
    assert (r"tps ($\lambda$ = 0.0347$\cdot\alpha^{2}$), $\pi^{\dagger}$($\tilde{x}$) $-$ 1 "
            r"$\rightarrow$ $\Delta$E $\leq$ $\ell$") in tex
    assert r"{\footnotesize note: \$5 \#1" in tex
    # the checker itself finds what is wrong
    assert latex_problems(tex.replace(r"\_1", "_1"), 3) and latex_problems(tex.replace(" & 8", " 8"), 3)
    assert latex_problems(tex.replace(r"\midrule", ""), 3) and latex_problems(tex + "{", 3)

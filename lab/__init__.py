"""The lab: the studies behind the tables and figures of docs/ (lab/studies/, each declared
once in lab/studies/__init__.py) and the generated parts of README.md and docs/
(lab/readme.py). It is not part of the installed package: it runs from a checkout, beside
driver/, and imports the package by its checkout name, driver.

    python -m lab study NAME ... | --group TARGET    (also: python -m driver study, make TARGET)
    python -m lab readme                              (also: python -m driver readme, make readme)
"""

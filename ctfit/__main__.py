"""``python -m ctfit``: the ``ctfit`` command, where the environment's scripts folder is not on
``PATH`` (a virtual environment not activated, a notebook's ``!python -m ctfit fit …``)."""

from ctfit.cli import console

if __name__ == "__main__":
    console()

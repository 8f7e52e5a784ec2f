"""What each command was asked to do: its options, each declared once (:mod:`.option`: the declaration; :mod:`.commands`:
every command's), and the ``--config`` file that may set some of them (:mod:`.config`). Above io (help texts name its
topics and shipped files), below the report, sweep and stages that read the options."""

# summary_key.sh - sourced by the bench scripts (not run on its own).
#
# key KEY FILE: the value of top-level KEY in the JSON file FILE (an
# hlod-bench summary.json, an hlod-build --json), empty when absent.
key() { perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
    my $v = $j->{$ARGV[0]}; print defined $v ? $v : ""' "$1" <"$2"; }

"""Every exemplar style from the command line: `sapga train --style S` writes a policy whose
`sapga eval` return equals its meta.value exactly; `sapga exemplars` lists and draws it;
`--init` seeds a run of the same style; a lockstep launch of it equals the offline episode."""
from __future__ import annotations

import json

import pytest

from sapga_ros.cli import main as cli
from sapga_ros.policies.runnable import load_policy
from sapga_ros.policies.styles import STYLES
from test_launch import launch, recorded_episodes, sapga_eval_json, the_bag


@pytest.fixture(scope='module')
def trained(tmp_path_factory):
    """One short acrobot SAP-GA run per style: {style: policy path}."""
    out = {}
    for style in STYLES:
        path = tmp_path_factory.mktemp('styles') / f'{style}.json'
        assert cli.main(['train', '--problem', 'acrobot', '--style', style, '--steps',
                         '150000', '--seed', '0', '--out', str(path), '--quiet']) == 0
        out[style] = path
    return out


@pytest.mark.parametrize('style', list(STYLES))
def test_eval_return_equals_the_trained_value(trained, style, capsys):
    """sapga eval of the written policy gives meta.value bit for bit (JSON round trip)."""
    capsys.readouterr()
    policy = load_policy(trained[style])
    assert policy.style == style
    result = sapga_eval_json(trained[style], capsys)
    assert result['return'] == policy.meta['value']
    assert result['delta_star'] == policy.meta['delta_star']


@pytest.mark.parametrize('style', list(STYLES))
def test_exemplars_lists_and_plots_every_style(trained, style, tmp_path, capsys):
    """The listing holds each exemplar's style fields; the plot is written; pruning keeps
    the episode."""
    capsys.readouterr()
    assert cli.main(['exemplars', str(trained[style]), '--json', '--plot',
                     str(tmp_path / 'ex.png'), '--prune-unused',
                     str(tmp_path / 'small.json')]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert set(STYLES[style].keys.values()) <= set(rows[0])
    assert (tmp_path / 'ex.png').stat().st_size > 10_000
    small = sapga_eval_json(tmp_path / 'small.json', capsys)
    assert small['return'] == load_policy(trained[style]).meta['value']


def test_init_seeds_a_run_of_the_same_style_only(trained, tmp_path, capsys):
    """--init with a policy of the run's style is accepted; of another style, one line, exit 2."""
    out = tmp_path / 'seeded.json'
    assert cli.main(['train', '--problem', 'acrobot', '--style', 'state-value', '--steps',
                     '20000', '--init', str(trained['state-value']), '--out', str(out),
                     '--quiet']) == 0
    assert load_policy(out).meta['value'] >= load_policy(trained['state-value']).meta['value']
    capsys.readouterr()
    assert cli.main(['train', '--problem', 'acrobot', '--style', 'via-point', '--steps',
                     '20000', '--init', str(trained['state-value']), '--out',
                     str(tmp_path / 'x.json'), '--quiet']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'state-value policy cannot seed a via-point run' in err[0]


@pytest.mark.parametrize('style', ['via-point', 'state-action-value'])
def test_swingup_launch_of_a_style_equals_sapga_eval(trained, style, tmp_path, capsys):
    """`sapga launch swingup --mode lockstep` of the policy records sapga eval's episode."""
    policy = tmp_path / 'p.json'
    policy.write_bytes(trained[style].read_bytes())
    done = launch(['swingup', '--policy', 'p.json', '--mode', 'lockstep', '--episodes', '1',
                   '--out', 'rec'], tmp_path)
    assert 'every lockstep episode is equal' in done.stdout
    (end,), rewards = recorded_episodes(the_bag(tmp_path / 'rec'))
    expected = sapga_eval_json(policy, capsys)
    assert (end['return'], end['step']) == (expected['return'], expected['steps'])
    assert len(rewards) == expected['steps']

"""eqhrl-report's reading of a run's episodes.csv."""

import pytest

from eqhrl_ros.reports.run_report import read_eval, read_runs

HEADER = 'episode,return,length,advice_asked,advice_given,success\n'


@pytest.mark.parametrize(
    'row,column',
    [('2,abc,100,1,1,0', 'return'), ('2,-5.0,100,1', 'advice_given'), ('2.5,-5.0,100,1,1,0', 'episode')],
    ids=['not a number', 'torn', 'fractional episode'],
)
def test_a_row_the_report_cannot_read_is_named_by_file_line_and_column(tmp_path, row, column):
    (tmp_path / 'episodes.csv').write_text(HEADER + '0,-9.5,100,3,3,0\n1,-7.0,100,2,1,1\n' + row + '\n')
    with pytest.raises(ValueError, match=rf'episodes.csv, line 4: {column} is .*, not a number this report can read'):
        read_runs([tmp_path])
    (tmp_path / 'episodes.csv').write_text(HEADER + '1,-7.0,100,2,1,1\n0,-9.5,100,3,3,0\n')
    (run,) = read_runs([tmp_path]).values()
    assert run['episode'].tolist() == [0.0, 1.0] and run['return'].tolist() == [-9.5, -7.0]


def test_a_torn_row_of_eval_csv_is_named_by_file_and_line(tmp_path):
    (tmp_path / 'eval.csv').write_text('algorithm,seed,episode,start,return\nsac,0,10,0,-120.5\nsac,0,10,1\n')
    with pytest.raises(ValueError, match=r'eval.csv, line 3: return is None, not a number'):
        read_eval([tmp_path])
    (tmp_path / 'eval.csv').write_text('algorithm,seed,episode,start,return\nsac,0,10,0,-120.5\nsac,0,10,1,-100.5\n')
    assert read_eval([tmp_path]) == {'sac': {10: [-110.5]}}


def test_a_folder_given_twice_is_refused_not_read_twice(tmp_path):
    (tmp_path / 'episodes.csv').write_text(HEADER + '0,-9.5,100,3,3,0\n')
    with pytest.raises(ValueError, match='is given more than once'):
        read_runs([tmp_path, tmp_path / '.'])
